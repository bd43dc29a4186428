"""Surface interactions: what happens where a ray meets a part. The extension point of the engine,
and the one place that decides which kind a part gets and what the estimators may do there.

Every kind declares (class attributes of :class:`Interaction`):

- ``roles``: the part roles it serves (``surface``, ``mirror``, ``absorber``, ``detector``);
- ``selected_by``: the material flags (:class:`materials.flags.ComponentFlags`) that choose it
  among the kinds of its role; ``NONE`` marks the role's default kind;
- ``terminal``: tallied by the hit stage itself (detection, absorption), never called;
- ``capabilities``: what the estimators may do with its vertices (:class:`Capability`), or, for a
  kind whose answer depends on the material, :meth:`Interaction.capabilities_for` (per material,
  from its flags), with ``material_classes`` / :meth:`Interaction.material_class` naming the
  material classes it tells apart (the contract test runs one scene per class).

:func:`kind_for` picks a part's kind from its role and its material's declared flags (never
from a name); :func:`part_kinds` gives every part's kind, :func:`part_handlers` what handles its
hits (:meth:`Interaction.handler_for`: the kind itself, or the algorithm it uses for that
material, carrying that material's capabilities) and :func:`parts_with` the parts whose material
allows a capability. The estimators (straylight.engine.nee, first_vertex, second_vertex, and the
target mixture) ask :func:`parts_with` / :class:`PartCapabilities`, so a kind says once, per
material, what it supports and the strategies follow (docs/engine.md, "Capabilities"). The
contract test (tests/straylight/test_engine_contract.py) runs every kind and material class
under every estimator.

Built-in kinds: ``detection`` (detector parts) and ``absorption`` (absorber parts), terminal;
``surface_response`` (surface parts: scatter lobes, Fresnel interfaces, or both, by the
material's flags; straylight.engine.interactions.surface_response) and ``delta_reflection``
(mirror parts), continuing. Modelled on Mitsuba 3 (``BSDFFlags`` read by
``src/integrators/path.cpp``) and pbrt-v4 (``BxDFFlags``, ``wavefront/surfscatter.cpp``).
"""
from __future__ import annotations

import numpy as np

from materials.flags import ComponentFlags, flags_of
from straylight.engine.capabilities import Capability
from straylight.engine.roles import ROLE_NAMES

INTERACTIONS: dict = {}  # name -> Interaction instance (names are labels for messages, never compared)


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

    name = ""  # a label for messages and docs
    roles: tuple = ()
    selected_by = ComponentFlags.NONE
    terminal = False  # tallied by the hit stage; never called
    capabilities = Capability.NONE  # the same for every material (else override capabilities_for)
    material_classes: tuple = ("",)  # the classes of materials it tells apart ("": one for all)

    def material_class(self, material=None) -> str:
        """Which of ``material_classes`` ``material`` belongs to."""
        return ""

    def capabilities_for(self, material=None) -> Capability:
        """What the estimators may do at a vertex on a part of this kind with ``material``."""
        return self.capabilities

    def allows(self, capability: Capability, material=None) -> bool:
        """Whether this kind declares ``capability`` (for ``material``)."""
        return bool(self.capabilities_for(material) & capability)

    def label(self, material=None) -> str:
        """The kind's name, with the material class where it tells several apart."""
        cls = self.material_class(material)
        return f"{self.name} ({cls})" if cls else self.name

    def handler_for(self, material=None):
        """What handles the continuing hits on a part with ``material``: an object with ``interact``,
        ``allows``, ``terminal`` and ``name`` (the kind itself, unless it dispatches per material).
        The walk groups the hits of an event by handler, in the order the parts first use them."""
        return self

    def interact(self, event, selection):
        raise NotImplementedError


class Handler:
    """The algorithm a kind uses for one class of materials, with the capabilities of those materials
    (:meth:`Interaction.handler_for`): ``allows`` answers for its parts, ``interact`` as
    :meth:`Interaction.interact`. One instance per (algorithm, capabilities): :func:`handler`."""

    terminal = False

    def __init__(self, name: str, capabilities: Capability) -> None:
        self.name = name
        self.capabilities = capabilities

    def allows(self, capability: Capability) -> bool:
        return bool(self.capabilities & capability)

    def interact(self, event, selection):
        raise NotImplementedError

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r}, {self.capabilities!r})"


_HANDLERS: dict = {}


def handler(algorithm: type, name: str, capabilities: Capability) -> Handler:
    """The one instance of ``algorithm`` (a :class:`Handler` subclass) labelled ``name`` with ``capabilities``."""
    key = (algorithm, name, capabilities)
    out = _HANDLERS.get(key)
    if out is None:
        out = _HANDLERS[key] = algorithm(name, capabilities)
    return out


def register_interaction(cls):
    """Class decorator: register one instance of ``cls`` under ``cls.name`` after checking its
    declarations (roles, and no two kinds of a role selected by the same flags)."""
    if not cls.name:
        raise ValueError(f"{cls.__name__} has no name")
    if cls.name in INTERACTIONS and type(INTERACTIONS[cls.name]) is not cls:
        raise ValueError(f"interaction {cls.name!r} is already registered by {type(INTERACTIONS[cls.name]).__name__}")
    if not cls.roles:
        raise ValueError(f"interaction {cls.name!r} declares no roles")
    for other in INTERACTIONS.values():
        if other.name == cls.name:
            continue
        shared = set(other.roles) & set(cls.roles)
        if shared and (other.selected_by == cls.selected_by or other.selected_by & cls.selected_by):
            raise ValueError(f"interaction {cls.name!r} and {other.name!r} are both selected by "
                             f"{cls.selected_by!r} for role(s) {', '.join(sorted(shared))}")
    INTERACTIONS[cls.name] = cls()
    return cls


def kind_for(role: str, material=None) -> Interaction:
    """The interaction kind of a part with ``role`` and (for a surface) ``material``: the kind of
    that role whose ``selected_by`` flags the material declares, else the role's default kind."""
    flags = flags_of(material) if material is not None else ComponentFlags.NONE
    default = None
    chosen = []
    for kind in INTERACTIONS.values():
        if role not in kind.roles:
            continue
        if kind.selected_by == ComponentFlags.NONE:
            default = kind
        elif flags & kind.selected_by:
            chosen.append(kind)
    if len(chosen) > 1:
        raise ValueError(f"material flags {flags!r} select several interactions for role {role!r}: "
                         f"{', '.join(k.name for k in chosen)}")
    if chosen:
        return chosen[0]
    if default is None:
        raise ValueError(f"no interaction kind serves role {role!r}; known: {', '.join(sorted(INTERACTIONS))}")
    return default


def _part_materials(spec) -> list:
    return [spec.materials[m] if m >= 0 else None for m in spec.part_material]


def part_kinds(spec) -> list:
    """The :class:`Interaction` of every part of ``spec`` (a TraceSpec), in part order."""
    return [kind_for(ROLE_NAMES[int(role)], m) for role, m in zip(spec.part_roles, _part_materials(spec))]


def part_handlers(spec) -> list:
    """What handles the hits on every part of ``spec``, in part order (:meth:`Interaction.handler_for`
    of the part's kind and material); each answers ``allows`` for its part's material."""
    return [kind.handler_for(m) for kind, m in zip(part_kinds(spec), _part_materials(spec))]


def parts_with(spec, capability: Capability) -> np.ndarray:
    """Bool per part: its kind allows ``capability`` for its material."""
    return PartCapabilities(part_handlers(spec)).parts(capability)


class PartCapabilities:
    """Per part of a scene, what its kind allows for its material (one per batch, on the walk's
    :class:`Event`): ``parts(cap)`` a bool array over the parts, ``at(cap, part)`` the same for an
    array of part ids. Built from the parts' handlers (anything with ``allows``, in part order)."""

    def __init__(self, handlers) -> None:
        self.handlers = list(handlers)
        self._cache: dict = {}

    def parts(self, capability: Capability) -> np.ndarray:
        out = self._cache.get(capability)
        if out is None:
            out = np.array([h.allows(capability) for h in self.handlers], dtype=bool)
            self._cache[capability] = out
        return out

    def at(self, capability: Capability, part) -> np.ndarray:
        return self.parts(capability)[part]


def kinds_with(spec, capability: Capability) -> list:
    """The distinct handlers in ``spec`` (a kind, or a kind's algorithm for a class of materials) that
    allow ``capability``, in first-appearance order; their ``name`` labels them for messages."""
    out = []
    for h in part_handlers(spec):
        if h.allows(capability) and h not in out:
            out.append(h)
    return out


def get_interaction(name: str) -> Interaction:
    try:
        return INTERACTIONS[name]
    except KeyError:
        raise ValueError(f"unknown surface interaction {name!r}; known: {', '.join(sorted(INTERACTIONS))}") from None
