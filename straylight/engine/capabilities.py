"""What the estimators may do with the vertices of an interaction kind: :class:`Capability`, declared by
every kind (straylight.engine.interactions.registry) and required by every estimator
(straylight.engine.estimators). A module of its own so that the estimator list does not import the
interaction kinds (docs/engine.md, "Capabilities")."""
from __future__ import annotations

import enum


class Capability(enum.Flag):
    """What the estimators may do with the vertices of an interaction kind."""

    NONE = 0
    #: next-event estimation toward the detectors from its vertices; a walk hit on a detector
    #: right after such a vertex keeps its MIS share against NEE (straylight.engine.hits)
    NEE = enum.auto()
    #: its parts may be area-sampled as the first scatter vertex (straylight.engine.first_vertex)
    FIRST_VERTEX = enum.auto()
    #: its vertices may start, and its parts hold, second-vertex samples (straylight.engine.second_vertex)
    SECOND_VERTEX = enum.auto()
    #: its scatter directions mix in target-part area sampling by MIS (straylight.engine.targets)
    TARGET_MIS = enum.auto()
    #: it turns unpolarized light into polarized light (Fresnel interfaces): estimators that
    #: evaluate their vertices unpolarized must stay out of scenes with it
    POLARIZES = enum.auto()
    #: a reflection at its interfaces that goes straight into a detector may be counted by its
    #: expected value instead of the walk's branch (straylight.engine.reflection_split)
    REFLECTION_SPLIT = enum.auto()
    #: its reflections and transmissions may be followed by splitting, both branches with their
    #: expected weights, through runs of such interfaces into a detector (straylight.engine.delta_chain)
    DELTA_CHAIN = enum.auto()
