"""Surface interactions: what happens where a ray meets a part. The extension point of the engine.

Every part gets one interaction kind, by name, from :func:`interaction_name` (its role, and for a
``surface`` part its material's ``interaction`` attribute, default ``"brdf_scatter"``). Kinds:

- terminal ones, tallied by the hit stage itself (straylight.engine.hits): ``detection``
  (detector parts) and ``absorption`` (absorber parts);
- continuing ones, called by the walk once per event with all the hits of their kind:
  ``brdf_scatter`` (importance-sample the material, NEE toward the detectors, target MIS) and
  ``delta_reflection`` (mirror parts: specular reflection, weight x R).

A new kind (refraction, Fresnel-split reflection, polarization...) is a subclass of
:class:`Interaction` registered with :func:`register_interaction` in a module imported by
``straylight/engine/interactions/__init__.py``; a material selects it by name
(``interaction = "my_kind"`` on its class). The walk does not change (docs/engine.md, "How to add
an interaction kind").
"""
from __future__ import annotations

INTERACTIONS: dict = {}  # name -> Interaction instance


class Interaction:
    """One kind of surface interaction.

    ``interact(event, selection) -> Outgoing`` handles the continuing hits
    ``event.hits.continuing[selection]`` (``selection``: a slice or an index array into the
    continuing hits; ``event.vertex_rows(selection)`` gives their rows in the event's per-ray arrays)
    and returns, one row per hit in order, the new direction, throughput, pdf, event code and side
    (:class:`straylight.engine.event.Outgoing`; :func:`straylight.engine.event.outgoing` builds one).
    It may add estimates to ``event.tallies`` (``add(row, ray, value)`` / ``subtract``; rows of
    ``event.rows``; keep the ledger exact: whatever it adds to a detector it subtracts from the
    part's ``nee_exchange`` row), record detector contributions with ``event.records.add`` and
    count its shadow rays in ``event.shadow_rays``. Absorption, Russian roulette, truncation and
    the next ray state are the walk's (straylight.engine.advance): they follow from ``throughput``.
    """

    name = ""
    terminal = False  # tallied by the hit stage; never called

    def interact(self, event, selection):
        raise NotImplementedError


def register_interaction(cls):
    """Class decorator: register one instance of ``cls`` under ``cls.name``."""
    if not cls.name:
        raise ValueError(f"{cls.__name__} has no name")
    if cls.name in INTERACTIONS and type(INTERACTIONS[cls.name]) is not cls:
        raise ValueError(f"interaction {cls.name!r} is already registered by {type(INTERACTIONS[cls.name]).__name__}")
    INTERACTIONS[cls.name] = cls()
    return cls


def interaction_name(role: str, material=None) -> str:
    """The interaction kind of a part with ``role`` and (for a surface) ``material``."""
    if role == "detector":
        return "detection"
    if role == "absorber":
        return "absorption"
    if role == "mirror":
        return "delta_reflection"
    return getattr(material, "interaction", None) or "brdf_scatter"


def get_interaction(name: str) -> Interaction:
    try:
        return INTERACTIONS[name]
    except KeyError:
        raise ValueError(f"unknown surface interaction {name!r}; known: {', '.join(sorted(INTERACTIONS))}") from None
