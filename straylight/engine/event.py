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


class Interfaces(NamedTuple):
    """What the Fresnel surface response (straylight.engine.interactions.optical_surface) hands the strategies that act
    at its hits (``Strategy.at_interfaces``: reflection_split, delta_chain), one row per hit, in order."""

    rows: np.ndarray  # rows of the event
    live: np.ndarray  # (m,) bool: not a pass-through
    refined: np.ndarray  # (m,) bool: refined onto the part's analytic surface (at ``exact``)
    exact: np.ndarray  # (m, 3) the refined point (where ``refined``)
    facing: np.ndarray  # (m, 3) normal on the incident side
    d: np.ndarray  # (m, 3) arriving direction
    s: np.ndarray  # (m, 3) s vector (materials.mueller.s_vector)
    S: np.ndarray  # (m, 4) arriving Stokes vector in the s/p basis
    fresnel: tuple  # (r_s, r_p, t_s, t_p, cos_t, eta, bulk) of each hit (surface_geometry.smooth_coefficients_into)
    E_r: np.ndarray  # (m,) expected reflected power fraction for this ray's polarization
    E_t: np.ndarray  # (m,) expected transmitted power fraction
    reflected: np.ndarray  # (m,) bool: the walk took the reflection branch
    transmitted: np.ndarray  # (m,) bool: the walk took the transmission branch
    passing: np.ndarray  # (m,) bool: a pass-through (refined outside the clear aperture or onto its origin)


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
    #: (strategy, state) of the running strategies that weigh scatter vertices (:meth:`vertex_weights`)
    vertex_hooks: tuple = ()
    #: (strategy, state) of the running strategies that act at Fresnel interfaces (:class:`Interfaces`)
    interface_hooks: tuple = ()
    #: ``blocked(origin, direction, tmax)``: the walk's shadow test (straylight.engine.diffraction.shadow_test)
    shadow_test: object = None
    shadow_rays: int = 0  # shadow rays cast by the interactions in this event

    def vertex_weights(self, verts):
        """MIS weights of the scatter vertices ``verts`` (rows of the event) from the strategies that also
        sample such vertices (``Strategy.vertex_weights``: first-vertex sampling); None: all 1. The scatter
        kinds call it once per event for their vertices, before NEE."""
        w = None
        for strategy, state in self.vertex_hooks:
            w = strategy.vertex_weights(state, self, verts, w)
        return w

    def claimed(self, rows) -> np.ndarray:
        """Of the interface hits ``rows``: those whose runs into a detector a strategy counts in full
        from here (straylight.engine.reverse_chain): reflection splits leave them."""
        out = np.zeros(len(rows), dtype=bool)
        for state in self.states.values():
            claims = getattr(state, "claims", None)
            if claims is not None:
                out |= claims(self, rows)
        return out

    def tree_share(self, rows, detector: int, arrival, walk_draws=None) -> np.ndarray:
        """The share a split tree rooted at the interface hits ``rows`` keeps of its score on
        ``detector``, its branches arriving along ``arrival`` (n, 3) (1 unless a strategy also counts
        that run: straylight.engine.reverse_chain); ``walk_draws`` (n,): the walk's draws of the tree's
        direction at its vertex, each of its density (straylight.engine.tree_split; None: one)."""
        out = np.ones(len(rows))
        for state in self.states.values():
            share = getattr(state, "tree_share", None)
            if share is not None:
                out *= share(self, rows, detector, arrival, walk_draws)
        return out

    def branch_share(self, rows, detector: int, z, nz, codes, k) -> np.ndarray:
        """The share a split-tree branch keeps of its score (rooted at the interface hits ``rows``, reaching
        ``detector`` at points ``z`` of triangle normals ``nz`` after ``k`` interfaces whose event codes are
        ``codes``): 1 unless a strategy also makes that very path (straylight.engine.specular_nee)."""
        out = np.ones(len(rows))
        for state in self.states.values():
            share = getattr(state, "branch_share", None)
            if share is not None:
                out *= share(self, rows, detector, z, nz, codes, k)
        return out

    def vertex_rows(self, selection) -> np.ndarray:
        """Rows (into the event's per-ray arrays) of the continuing hits ``selection``."""
        return self.hits.continuing[selection]
