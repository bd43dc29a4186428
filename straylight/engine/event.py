"""What a surface interaction sees of one event (:class:`Event`) and what it hands back
(:class:`Outgoing`). Built by the walk (straylight.engine.walk) once per event."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np


class Outgoing(NamedTuple):
    """Where each continuing ray goes next: what an interaction returns for the hits it was given
    (one row each, in order); the walk puts the kinds' answers together, one row per entry of
    ``Event.hits.continuing``."""

    direction: np.ndarray  # (n, 3) unit, world frame
    throughput: np.ndarray  # (n,) weight factor: new weight = weight x throughput (0: absorbed)
    pdf_per_sr: np.ndarray  # (n,) density of the sampled direction (for MIS with NEE); 0 for a delta event
    event: np.ndarray  # (n,) int8 event code recorded in the path (EVENT_SCATTER, EVENT_SPECULAR)
    side: np.ndarray  # (n,) int8: +1 the ray leaves on the side it came from, -1 it crosses the surface


def outgoing(direction, throughput, pdf_per_sr, event_code: int, side: int = 1) -> Outgoing:
    """An :class:`Outgoing` whose rows all have the same event code and side."""
    n = len(throughput)
    return Outgoing(direction=np.ascontiguousarray(direction, dtype=np.float64),
                    throughput=np.ascontiguousarray(throughput, dtype=np.float64),
                    pdf_per_sr=np.ascontiguousarray(pdf_per_sr, dtype=np.float64),
                    event=np.full(n, event_code, dtype=np.int8), side=np.full(n, side, dtype=np.int8))


def combined_outgoing(n: int, parts) -> Outgoing:
    """One :class:`Outgoing` of ``n`` rows from ``parts`` = [(selection, Outgoing of those rows)]."""
    out = Outgoing(direction=np.empty((n, 3)), throughput=np.empty(n), pdf_per_sr=np.empty(n),
                   event=np.empty(n, dtype=np.int8), side=np.empty(n, dtype=np.int8))
    for selection, part in parts:
        for column, value in zip(out, part):
            column[selection] = value
    return out


@dataclass
class Event:
    """One event of a batch: the rays before it, what they hit, their uniforms, and where the
    estimates go. ``kernels`` is the walk's kernel set (compiled, or the numpy twins)."""

    spec: object  # TraceSpec
    scene: object  # CompiledScene
    kernels: object  # straylight.engine.kernel_sets.KernelSet
    settings: object  # WalkSettings
    rows: object  # TallyRows
    tallies: object  # the batch's tally store (straylight.engine.tally_store: add / subtract / reserve)
    records: object  # straylight.engine.tallies.DetectorRecords
    rays: object  # RayBatch before the event
    tri: np.ndarray  # triangle hit by each ray (-1: miss)
    hits: object  # straylight.engine.hits.Hits
    uniforms: np.ndarray  # (live rays, columns.width)
    columns: object  # straylight.engine.draws.EventColumns
    capabilities: object = None  # straylight.engine.interactions.registry.PartCapabilities of the parts
    #: the per-batch states of the strategies running in this batch, by their ``state_key``
    #: (straylight.engine.strategies.base.Strategy.batch_state); a strategy not running has none
    states: dict = field(default_factory=dict)
    #: (strategy, state) of the running strategies with hooks into next-event estimation (straylight.engine.nee)
    nee_hooks: tuple = ()
    #: ``blocked(origin, direction, tmax)``: the walk's shadow test (straylight.engine.diffraction.shadow_test)
    shadow_test: object = None
    shadow_rays: int = 0  # shadow rays cast by the interactions in this event

    @property
    def first_vertex(self):
        """straylight.engine.first_vertex.FirstVertexWeights, or None."""
        return self.states.get("first_vertex")

    @property
    def second_vertex(self):
        """straylight.engine.second_vertex.SecondVertexShares (second-vertex lobe sampling), or None."""
        return self.states.get("second_vertex")

    @property
    def reflection_split(self):
        """straylight.engine.reflection_split.ReflectionSplit, or None."""
        return self.states.get("reflection_split")

    @property
    def delta_chain(self):
        """straylight.engine.delta_chain.DeltaChains, or None."""
        return self.states.get("delta_chain")

    def vertex_rows(self, selection) -> np.ndarray:
        """Rows (into the event's per-ray arrays) of the continuing hits ``selection``."""
        return self.hits.continuing[selection]
