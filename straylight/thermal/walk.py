"""The one walk of the thermal estimators, in numpy over Embree: from start points, cast, end the
rays that leave the scene or meet an absorber or detector, let the others interact with the
surface (straylight.thermal.interaction), play Russian roulette, and go on. What an estimator
scores along the way (its *pickup*) is passed in: ``at_hit`` sees every event's hits before the
surface interaction, ``after_scatter`` the weights the interaction and roulette leave.

Per event a ray draws ``EVENT_COLUMNS`` uniforms from its chunk's stream: 0 picks the branch
(lobes / specular / transmission), 1..3 go to the material's ``sample``, 4 to roulette, 5..7 to
next-event estimation. Chunks and streams are the engine's (straylight.rng): a walk traces a batch
of whole chunks of ``straylight.rng.CHUNK_RAYS`` rays, each ray drawing from its chunk's
``chunk_rng(seed, id)`` (``straylight.rng.BatchDraws``; ids from ``stream_chunk``), so results do not
depend on how chunks are grouped or spread over threads (CONTRACTS §1). Russian roulette is the engine's rule (straylight.engine.roulette) at the engine's
default threshold (``EstimatorOptions.rr_threshold`` times the start weight).

Limits (docs/thermal.md): facet normals (no refinement onto analytic surfaces), unpolarized
(the mean of s and p at every Fresnel interface), no bulk absorption or bulk emission in
dielectrics, reverse walks use f(wi, wo) with wi and wo swapped (exact for reciprocal BRDFs).
"""
from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from straylight.engine.options import EstimatorOptions
from straylight.engine.roulette import survivor_weights
from straylight.rng import CHUNK_RAYS
from straylight.run_checks import TruncationWarning
from straylight.thermal.interaction import interact

EVENT_COLUMNS = 8
BATCH_CHUNKS = 8  # whole chunks traced together in one walk (numpy's per-event costs shared by their rays)
ROULETTE_W = EstimatorOptions().rr_threshold  # the engine's, relative to the start weight (w_ref)
MAX_EVENTS = 100_000  # a bound, not a truncation: roulette ends the paths long before (mirror boxes need thousands)


def chunk_counts(n_rays: int) -> list:
    """The rays of each chunk of ``n_rays`` rays: whole chunks of CHUNK_RAYS, then the rest."""
    full, rest = divmod(int(n_rays), CHUNK_RAYS)
    return [CHUNK_RAYS] * full + ([rest] if rest else [])


def batches_of(chunk_ids, counts, per: int = BATCH_CHUNKS):
    """``(chunk_ids, counts)`` of consecutive runs of at most ``per`` chunks (whole chunks, the last may
    be short): the batches one walk traces (straylight.rng.BatchDraws)."""
    return [(list(chunk_ids[a:a + per]), list(counts[a:a + per])) for a in range(0, len(counts), per)]


@dataclass
class Hit:
    """Where the rays of one event ended (rows of the live rays; ``tri`` -1 = escaped)."""

    tri: np.ndarray
    part: np.ndarray
    point: np.ndarray  # (n, 3)
    cos: np.ndarray  # d . n (n the triangle's front normal): < 0 arriving on the front
    facing: np.ndarray  # (n, 3) normal turned toward the incoming ray

    @property
    def front(self) -> np.ndarray:
        return self.cos < 0

    @property
    def theta(self) -> np.ndarray:
        return np.arccos(np.clip(np.abs(self.cos), 0.0, 1.0))


def cast(ts, o, d) -> Hit:
    """First hits of rays (o, d) by the scene's intersector (which counts a hit on an analytic plane
    part only inside its exact boundary: straylight.intersect.exact_boundary); distances from the
    triangle planes in float64."""
    tri = np.asarray(ts.intersector.first_triangle(o, d), dtype=np.int64)
    ok = tri >= 0
    k = np.where(ok, tri, 0)
    n = ts.normals[k]
    cos = np.einsum("ij,ij->i", d, n)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ts.plane_d[k] - np.einsum("ij,ij->i", n, o)) / cos
    t = np.where(ok & np.isfinite(t), np.maximum(t, 0.0), 0.0)
    point = o + t[:, None] * d
    facing = np.where((cos < 0)[:, None], n, -n)
    return Hit(tri=np.where(ok, tri, -1), part=np.where(ok, ts.triangle_part[k], -1), point=point, cos=cos,
               facing=facing)


@dataclass
class Event:
    """One event of the rays still walking (one row each), as a pickup sees it."""

    ray: np.ndarray  # (n,) each row's ray number in the chunk (0 .. N-1)
    d: np.ndarray  # (n, 3) the directions that arrived
    w: np.ndarray  # (n,) the weights that arrived
    delta: np.ndarray  # (n,) bool: the ray left its last vertex by a specular or refracted branch
    hit: Hit
    ends: np.ndarray  # (n,) bool: escaped, or on an absorber or detector (the walk stops there)
    cont: np.ndarray  # row indices that interact and go on (the rows not in ``ends``)
    U: np.ndarray  # (n, EVENT_COLUMNS) this event's uniforms
    capped: bool = False  # the event cap (MAX_EVENTS): every path ends here, what it carries is dropped
    carried: np.ndarray | None = None  # at the cap: the rows ``cont``'s weights after this interaction (dropped)

    @property
    def alive(self) -> np.ndarray:
        """(n,) bool: the rows that hit a part."""
        return self.hit.tri >= 0


CAP_MESSAGE = ("the thermal walk's event cap ({cap} events) stopped paths still carrying over 1 % of their "
               "power (a closed mirror cavity): that power is not counted; give the cavity an absorbing or "
               "escaping part")


def walk(ts, sides, draws, o, nrm, d, w, at_hit: Callable[[Event], None],
         after_scatter: Callable[[Event, np.ndarray], None] | None = None, w_ref: float = 1.0,
         warn_cap: bool = True) -> None:
    """Walk rays from points ``o`` (n, 3) on surfaces of normals ``nrm`` (started ``ts.eps_mm`` off
    them) along ``d`` with weights ``w`` through ``ts`` (straylight.thermal.model.ThermalScene) with
    the materials ``sides`` (model.SideTables), drawing each event's uniforms from ``draws``
    (straylight.rng.BatchDraws: each ray from its own chunk's stream).

    ``at_hit(event)`` scores the hits of every event; ``after_scatter(event, w_next)`` the rows
    ``event.cont`` after interaction and roulette (``w_next``: their weights now, 0 where the path
    ends; at the event cap every path ends with 0 and ``event.capped`` is set: callers report that
    power as cut, never as absorbed by the part hit). Roulette plays below ``ROULETTE_W * w_ref``.
    ``warn_cap``: a TruncationWarning (:data:`CAP_MESSAGE`) when the paths stopped at the cap still
    carry more than 1 % of the starting weight (callers that report it themselves pass False)."""
    w_start = float(np.sum(w))
    o = o + ts.eps_mm * nrm
    ray = np.arange(len(w))
    delta = np.zeros(len(w), bool)
    terminal = ts.is_role("absorber", "detector")
    for index in range(MAX_EVENTS):
        if len(ray) == 0:
            break
        U = draws.uniforms(ray, EVENT_COLUMNS)
        hit = cast(ts, o, d)
        alive = hit.tri >= 0
        ends = ~alive | terminal[np.where(alive, hit.part, 0)]
        cont = np.flatnonzero(~ends)
        ev = Event(ray, d, w, delta, hit, ends, cont, U, capped=index == MAX_EVENTS - 1)
        at_hit(ev)
        if len(cont) == 0:
            break
        out = interact(ts, sides, hit, cont, d[cont], U[cont])
        w_next = survivor_weights(w[cont] * out.throughput, ROULETTE_W * float(w_ref), U[cont, 4])
        if index == MAX_EVENTS - 1:
            ev.carried = w_next
            if warn_cap and float(np.sum(w_next)) > 0.01 * w_start:
                warnings.warn(CAP_MESSAGE.format(cap=MAX_EVENTS), TruncationWarning, stacklevel=2)
            w_next = np.zeros_like(w_next)  # the cap: every path ends here
        if after_scatter is not None:
            after_scatter(ev, w_next)
        keep = w_next > 0
        c = cont[keep]
        o = hit.point[c] + (ts.eps_mm * out.side[keep])[:, None] * hit.facing[c]
        d = out.direction[keep]
        w = w_next[keep]
        delta = out.delta[keep]
        ray = ray[c]
