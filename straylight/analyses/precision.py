"""Ask for precision, not rays: trace in growing rounds until the relative standard error is reached.

Round ``r`` traces the ray ids right after the previous rounds' (``trace(..., execution=Execution(first_chunk=K))``:
the random streams of chunks K, K+1, ... of the same seed), so the rounds together are the first N
rays of one long run: the same seed and target give the same rounds and the same numbers, and the
merged estimate equals a single trace of N rays (:func:`merge_results`, exact pooled sums).

**Looking ahead.** A walk call costs ~0.1 CPU s of its own (the per-event work of every strategy, paid
whatever its rays), and the rule cannot stop before a look that meets the target has been confirmed by
one with ``confirm_growth`` more rays, at the minimum sample at the earliest (6e4 rays by default). So
each call traces on to the earliest look the run can stop at (:func:`traced_before_look`), and the
looks before it are read from the first rays' chunk sums: the same looks, the same stop and the same
rays as a call per look (to round-off), in fewer calls. A point that stops at the minimum sample is one
call of 6e4 rays instead of three of 2e4 (~0.1 CPU s less per point on the guide scope). Under a time cap
a call looks ahead only as far as the time left allows at the rate so far, and the first call (no rate
yet) only under a cap of at least :data:`LOOK_AHEAD_MIN_CAP_S`; only a time cap can end a run inside
rays traced ahead, which then keeps them all.

Stop rules (the first that holds ends the point; ``stop_reason`` says which):

``target``
    relative standard error <= E **and** the error estimate is reliable: the variance of the
    variance (VOV) <= ``max_vov``. A rare heavy path (a ray carrying a large share of the power)
    makes the error estimate itself swing; the VOV measures that (MCNP's statistical check: the
    relative variance of the estimated variance of the mean, ``VOV = sum (x - m)^4 /
    (sum (x - m)^2)^2 - 1/N``, recommended < 0.1; X-5 Monte Carlo Team, *MCNP - A General Monte
    Carlo N-Particle Transport Code, Version 5*, LA-UR-03-1987, vol. I, §2.VI.D). Here it is
    estimated from the per-chunk sums of the engine (1000-ray chunks): with
    ``c_k = sum over chunk k of (x - m)^2``, ``VOV = Var(sum c_k) / (sum c_k)^2``, the same quantity
    in expectation. ``rel_error_of_error = sqrt(VOV) / 2`` (delta method).
    Three guards against stopping on a lucky start (optional stopping with heavy-tailed path
    weights: a short run that has not yet drawn a rare heavy path is low *and* looks precise; the
    looks that pass first are exactly those runs; docs/decisions.md, "the precision stop"):

    - **minimum sample**: no stop before ``min_chunks`` independent 1000-ray chunks (the VOV and the
      variance need enough batches to be estimated at all);
    - **a confirming look**: the target (error and VOV) must hold on two successive looks, the later
      with at least ``confirm_growth`` more rays, and the estimate must not have moved between them
      by more than ``max_jump`` times the later standard error (a heavy path drawn between two looks
      shows as a jump);
    - **tail check**: no single chunk may hold more than ``max_chunk_share`` of the variance (one
      heavy ray dominating the error estimate means its tail is not sampled yet).
``max_rays`` / ``max_seconds``
    the cap was reached first (the estimate is kept, with its error and VOV).

The error a precision run reports is tail-aware: the sample standard error times ``1 + sqrt(VOV)``
(twice the estimated relative error of the error, :func:`tail_aware`). With heavy-tailed path
weights the sample error is correlated with the estimate (a run that drew fewer heavy paths is low
*and* reports a small error); the factor is ~1 where the error estimate is solid (VOV ~ 0) and widens
the bar only where it is not. On the heavy-tailed model of tests/straylight/test_precision_stop.py it
brings the RMS z-score from 1.22-1.32 to 1.02-1.13. Runs of a fixed ray count report the plain error.
"""
from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from straylight.execution import Execution, as_execution
from straylight.rng import CHUNK_RAYS

from straylight.stop_rule import (  # noqa: F401 - the rule lives below the runs (thermal uses it)
    DEFAULT_CONFIRM_GROWTH, DEFAULT_FIRST_RAYS, DEFAULT_MAX_CHUNK_SHARE, DEFAULT_MAX_JUMP, DEFAULT_MAX_RAYS,
    DEFAULT_MAX_VOV, DEFAULT_MIN_CHUNKS, MAX_GROWTH, SAFETY, Look, Precision, Reliability, _chunk_rays,
    next_round_rays, reliability, tail_aware,
)

if TYPE_CHECKING:
    from straylight.engine.results import TraceResult


# ------------------------------------------------------------------ merging rounds exactly

def _merge_pair(parts):
    """[(n_rays, power, stderr), ...] -> (power, stderr) of the pooled N = sum n rays (exact sums).

    A round of n rays has per-ray contributions x = y / n (y: the ray's estimate of the total);
    power = sum x, stderr^2 = (sum x^2 - (sum x)^2 / n) n / (n - 1). The pooled estimate over all
    rays is sum y / N with the same formula on the pooled sums of y and y^2.
    """
    n_tot = sum(n for n, _, _ in parts)
    y1 = y2 = 0.0
    for n, p, e in parts:
        s2 = (e * e * (n - 1) / n + p * p / n) if n > 1 else p * p
        y1 = y1 + n * np.asarray(p, dtype=np.float64)
        y2 = y2 + n * n * np.asarray(s2, dtype=np.float64)
    power = y1 / n_tot
    if n_tot < 2:
        return power, np.zeros_like(power)
    var = (y2 / n_tot**2 - power * power / n_tot) * (n_tot / (n_tot - 1.0))
    return power, np.sqrt(np.maximum(var, 0.0))


def _merge_tallies(results, get):
    from straylight.trace import Tally

    p, e = _merge_pair([(r.n_rays, get(r).power_w, get(r).stderr_w) for r in results])
    return Tally(float(p), float(e))


def _merge_dict(results, get):
    keys = get(results[0]).keys()
    return {k: _merge_tallies(results, lambda r, k=k: get(r)[k]) for k in keys}


def merge_results(results) -> TraceResult:
    """One TraceResult from rounds that traced consecutive ray ids of one seed (see module doc)."""
    from straylight.detectors import IrradianceMap
    from straylight.paths import PathRecords

    if len(results) == 1:
        return results[0]
    first = results[0]
    n_tot = sum(r.n_rays for r in results)
    maps = {}
    for name, m in first.maps.items():
        p, e = _merge_pair([(r.n_rays, r.maps[name].power_w, r.maps[name].stderr_w) for r in results])
        maps[name] = IrradianceMap(m.edges_u_mm, m.edges_v_mm, p, e, m.origin_mm, m.axis_u, m.axis_v, m.normal)
    ledger = {}
    for key, val in first.ledger.items():
        if isinstance(val, dict):
            ledger[key] = _merge_dict(results, lambda r, key=key: r.ledger[key])
        elif key == "balance_residual_w":
            continue
        else:
            ledger[key] = _merge_tallies(results, lambda r, key=key: r.ledger[key])
    detectors = _merge_dict(results, lambda r: r.detectors)
    absorbed = _merge_dict(results, lambda r: r.absorbed)
    escaped = _merge_tallies(results, lambda r: r.escaped)
    ledger["balance_residual_w"] = float(first.emitted_w - (sum(t.power_w for t in detectors.values())
                                                            + sum(t.power_w for t in absorbed.values())
                                                            + escaped.power_w))
    paths = None
    if first.paths is not None:
        pieces, offset = [], 0
        for r in results:
            rec = r.paths
            pieces.append({"ray": rec.ray + offset, "detector": rec.detector, "power_w": rec.power_w * (r.n_rays / n_tot),
                           "depth": rec.depth, "key": rec.key, "events": rec.events})
            offset += r.n_rays
        paths = PathRecords.concatenate(pieces, first.paths.part_names, n_tot, first.paths.events.shape[1])
    chunks = None
    if all(r.detector_chunks is not None for r in results):
        # per-chunk sums in units of the pooled run: x_pooled = x_round * n_round / N
        chunks = {name: (np.concatenate([r.detector_chunks[name][0] * (r.n_rays / n_tot) for r in results]),
                         np.concatenate([r.detector_chunks[name][1] * (r.n_rays / n_tot) ** 2 for r in results]))
                  for name in first.detector_chunks}
    return replace(first, n_rays=n_tot, detectors=detectors, maps=maps, absorbed=absorbed, escaped=escaped,
                   incident=_merge_dict(results, lambda r: r.incident),
                   first_hit=_merge_dict(results, lambda r: r.first_hit), ledger=ledger, paths=paths,
                   segments=sum(r.segments for r in results), shadow_rays=sum(r.shadow_rays for r in results),
                   detector_chunks=chunks)


# ------------------------------------------------------------------ tracing to a target

@dataclass
class PrecisionRun:
    """A merged trace and how it stopped: ``stop_reason`` is target, max_rays or max_seconds."""

    result: TraceResult
    stop_reason: str
    rounds: list = field(default_factory=list)  # (rays so far, rel_error, vov) after each round
    seconds: float = 0.0
    reliability: dict = field(default_factory=dict)  # detector name -> Reliability

    def summary(self) -> dict:
        return {"stop_reason": self.stop_reason, "rays": int(self.result.n_rays), "seconds": self.seconds,
                "rounds": [{"rays": n, "rel_error": _clean(e), "vov": _clean(v)} for n, e, v in self.rounds],
                "reliability": {k: v.to_dict() for k, v in self.reliability.items()}}


def _clean(x):
    return None if x is None or (isinstance(x, float) and not math.isfinite(x)) else float(x)


def _worst(rel: dict):
    """The detector that decides: largest relative error (NaN, i.e. nothing detected, counts as worst)."""
    items = list(rel.values())
    if not items:
        return math.nan, math.nan
    errs = [math.inf if not math.isfinite(r.rel_error) else r.rel_error for r in items]
    i = int(np.argmax(errs))
    return items[i].rel_error, items[i].vov


def _look(merged, rel: dict, n_done: int) -> Look:
    """The stop rule's view: the worst detector's error, VOV, chunk share, and its estimate."""
    if not rel:
        return Look(n_done, 0.0, math.nan, math.nan, math.nan, 0)
    name = max(rel, key=lambda k: math.inf if not math.isfinite(rel[k].rel_error) else rel[k].rel_error)
    r = rel[name]
    estimate = (merged.detectors[name].power_w if n_done >= merged.n_rays  # a look inside the rays traced ahead:
                else np.sum(_first_chunks(merged, name, n_done)[0]))  # the first rays' own estimate
    return Look(n_done, float(estimate), r.rel_error, r.vov, r.max_chunk_share, r.chunks)


def trace_to_precision(scene, sources, seed, precision: Precision, materials=None, options=None,
                       detectors=None, on_round=None, execution: Execution | None = None,
                       look_ahead: bool = True) -> PrecisionRun:
    """Trace in growing rounds until every detector in ``detectors`` (default: all) reaches the
    target (see the module docstring). ``execution``: where each round runs (:func:`straylight.trace.trace`).
    ``on_round``: a callable(str) told about each round (e.g. a tqdm bar's set_postfix_str).

    ``look_ahead`` (default): each call traces on to the earliest look the run can stop at
    (:func:`traced_before_look`), and the looks before it read the first rays' chunk sums: the same
    looks, the same stop and the same rays as one call per look (to round-off), in fewer walk calls
    (each costs ~0.1 CPU s of its own; one call of 6e4 rays where a point stops at the minimum sample
    instead of three). Off: one call per look."""
    from straylight.trace import trace

    t0 = time.perf_counter()
    results: list = []
    merged = None
    rounds = []
    n_done = n_traced = 0
    next_n = _chunk_rays(min(precision.first_rays, precision.max_rays))
    stop = None
    rel: dict = {}
    looks: list = []
    while True:
        n_look = n_done + next_n
        if n_look > n_traced:
            upto = _traced_ahead(looks, n_look, precision, n_traced, time.perf_counter() - t0) if look_ahead else n_look
            results.append(trace(scene, sources, upto - n_traced, seed, materials=materials, options=options,
                                 execution=replace(as_execution(execution), first_chunk=n_traced // CHUNK_RAYS)))
            n_traced = upto
            merged = merge_results(results)
        assert merged is not None  # the first look always traces
        n_done = n_look
        names = list(detectors) if detectors is not None else list(merged.detectors)
        rel = {name: reliability(*_first_chunks(merged, name, n_done), n_done) for name in names}
        err, vov = _worst(rel)
        rounds.append((n_done, err, vov))
        looks.append(_look(merged, rel, n_done))
        # the time the rule would have spent on its n_done rays (the rays traced ahead cost the same each)
        elapsed = (time.perf_counter() - t0) * n_done / n_traced
        if on_round is not None:
            on_round(f"{n_done:.3g} rays, rel. error {err:.2%}, VOV {vov:.2g}" if math.isfinite(err)
                     else f"{n_done:.3g} rays, nothing detected yet")
        if precision.stops(looks):
            stop = "target"
        elif n_done >= precision.max_rays:
            stop = "max_rays"
        elif elapsed >= precision.max_seconds:
            stop = "max_seconds"
        if stop:
            break
        next_n = next_round_rays(looks, precision, elapsed)
    if n_done < n_traced:  # a time cap ended the run inside the rays traced ahead: keep them all
        rel = {name: reliability(*merged.chunks_of(name), n_traced) for name in rel}
    return PrecisionRun(_widened(merged, rel), stop, rounds, time.perf_counter() - t0, rel)


#: a time cap below this many seconds keeps the first call to the first round (no per-ray cost is known yet)
LOOK_AHEAD_MIN_CAP_S = 30.0


def _traced_ahead(looks: list, n_look: int, precision: Precision, n_traced: int, spent_s: float) -> int:
    """:func:`traced_before_look`, within a time cap: as far as the time left allows at the rate so far
    (the first call: only under a cap of at least :data:`LOOK_AHEAD_MIN_CAP_S`), never short of the look."""
    upto = traced_before_look(looks, n_look, precision)
    if math.isfinite(precision.max_seconds):
        if n_traced == 0:
            fits = upto if precision.max_seconds >= LOOK_AHEAD_MIN_CAP_S else n_look
        else:
            left = max(precision.max_seconds - spent_s, 0.0) * n_traced / max(spent_s, 1e-9)
            fits = n_traced + int(left // CHUNK_RAYS) * CHUNK_RAYS
        upto = min(upto, fits)
    return max(upto, n_look)


def traced_before_look(looks: list, n_look: int, precision: Precision) -> int:
    """Rays to have traced before the look at ``n_look`` (after ``looks``): that look's own when it can
    end the run (the look before it met the target: it is the confirming look), else the earliest look
    any later stop can be at: a stop needs a look that meets the target (at least the minimum sample
    and at least ``n_look``) and a confirming look with ``confirm_growth`` more rays after it
    (:func:`straylight.stop_rule.next_round_rays` never plans it nearer); within ``max_rays``."""
    if looks and precision.meets(looks[-1]):
        return n_look
    meets_at = max(n_look, precision.min_chunks * CHUNK_RAYS)
    confirm = meets_at + _chunk_rays(int(max(precision.confirm_growth * meets_at, CHUNK_RAYS)))  # as next_round_rays rounds
    return int(min(max(confirm, n_look), precision.max_rays))


def _first_chunks(merged, name: str, n_rays: int) -> tuple[np.ndarray, np.ndarray]:
    """The per-chunk sums of ``name`` over the first ``n_rays`` rays of ``merged``, in the units of a run
    of ``n_rays`` rays (x = y / n_rays: the chunks of a result of N rays scaled by N / n_rays)."""
    s1, s2 = merged.chunks_of(name)
    if n_rays >= merged.n_rays:
        return s1, s2
    k = n_rays // CHUNK_RAYS
    f = merged.n_rays / n_rays
    return s1[:k] * f, s2[:k] * (f * f)


def _widened(result, rel: dict):
    """The merged result with each decided detector's standard error made tail-aware (:func:`tail_aware`)."""
    from straylight.trace import Tally

    detectors = copy.copy(result.detectors)  # keeps an AliasDict's aliases
    for name, r in rel.items():
        t = detectors[name]
        if math.isfinite(r.vov):
            dict.__setitem__(detectors, name, Tally(t.power_w, t.stderr_w * (1.0 + math.sqrt(max(r.vov, 0.0)))))
    return replace(result, detectors=detectors)
