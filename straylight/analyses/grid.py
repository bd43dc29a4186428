"""One way to run a grid of points: :func:`run_grid`, used by ``pst``, ``study``, the
``--model`` sweeps, the built-in tube's design sweep and ``design vanes``.

A grid is a list of :class:`GridPoint` (a checkpoint key, a seed, a label); for each point the
analysis says what to trace (a :class:`TraceJob`: scene, sources, materials, options, the detector
whose power is the result, and the point's derived numbers, e.g. its PST). The runner, the same for
every analysis:

- runs under one :class:`straylight.execution.Execution` (one dask cluster for the whole grid, or
  threads, or this process; never a different number);
- traces each point with a fixed ray count, or to a precision target
  (:class:`straylight.analyses.precision.Precision`: target relative error, the VOV gate on the
  error's own reliability, a ray cap and a time budget per point; :func:`trace_to_precision`);
- writes each finished point to a checkpoint (:class:`straylight.checkpoints.PointStore`: the
  fingerprint of the run and a checksum per point) and, on resume, reads back the finished points
  instead of tracing them (each point has its own seed: the same numbers whichever run traced it);
- shows one progress bar (points done, the current point's label and its precision rounds) on stderr
  when the execution asks for progress.

The numbers of a point are computed once, when it is traced (``TraceJob.values``), and kept in the
checkpoint as they are: a resumed grid returns exactly the floats of an uninterrupted one.
"""
from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from straylight.analyses.heaviest import heaviest_path, untrusted
from straylight.analyses.precision import Precision, reliability, trace_to_precision
from straylight.checkpoints import PointStore
from straylight.execution import Execution, as_execution
from straylight.progress import progress_bar
from straylight.trace import trace


def point_seed(seed: int, index: int) -> int:
    """Seed of the ``index``-th point of a grid: independent streams from one user seed."""
    return int(np.random.SeedSequence([int(seed), int(index)]).generate_state(1)[0])


@dataclass(frozen=True)
class GridPoint:
    """One point of a grid.

    key : its index in the checkpoint (unique within one store)
    seed : the seed its trace uses
    label : shown beside the progress bar while it is traced
    tag : a JSON value a checkpointed point must carry too to be read back (else it is traced again;
        ``design vanes`` tags each point with its layout)
    """

    key: int
    seed: int
    label: str = ""
    tag: object = None


@dataclass(frozen=True)
class TraceJob:
    """What to trace for one point, and what to keep from it.

    values : tally -> dict of the point's numbers (JSON-able floats; e.g. its PST and error) from the
        detector's :class:`straylight.trace.Tally`; computed once, when the point is traced
    """

    scene: object
    sources: list
    materials: dict | None
    options: object
    detector: str
    values: Callable[[object], dict] = field(default=lambda tally: {})


@dataclass(frozen=True)
class PointRun:
    """One finished point: its numbers (``values``), the rays traced, the wall time of its trace, the
    reliability of its error estimate (``diagnostics``: vov, rel_error_of_error, max_chunk_share; with a
    precision target also stop_reason and rounds; strategies_off: the strategies asked for that did not run
    and why, e.g. the eye chains where their pilot found they carry too little of the light), and its
    TraceResult when the grid keeps traces."""

    values: dict
    rays: int
    seconds: float
    diagnostics: dict
    trace: object = None

    def record(self, tag) -> dict:
        """What the checkpoint keeps (the trace is not kept)."""
        return {"values": self.values, "rays": int(self.rays), "seconds": float(self.seconds),
                "diagnostics": self.diagnostics, "tag": tag}

    @classmethod
    def from_record(cls, doc: dict) -> PointRun:
        return cls(dict(doc["values"]), int(doc["rays"]), float(doc["seconds"]), dict(doc["diagnostics"]))


def _diagnostics(rel) -> dict:
    d = rel.to_dict()
    return {"vov": d["vov"], "rel_error_of_error": d["rel_error_of_error"], "max_chunk_share": d["max_chunk_share"]}


def _restored(store, point: GridPoint) -> PointRun | None:
    """The point as an earlier run finished it (None: not finished, no store, or another tag)."""
    saved = store.get(point.key) if store is not None else None
    if saved is None or saved.get("tag") != point.tag:
        return None
    return PointRun.from_record(saved)


def run_grid(points, job: Callable[[GridPoint], TraceJob], execution: Execution | None = None, *,
             rays: int | None = None, precision: Precision | None = None, checkpoint=None, desc: str = "grid",
             unit: str = "point", keep_traces: bool = False) -> list[PointRun]:
    """Trace every point of ``points`` (see the module docstring); returns their :class:`PointRun` in order.

    job : point -> :class:`TraceJob`, called only for points still to trace (a design's scene is built
        only when one of its points is)
    execution : where to run (:class:`straylight.execution.Execution`; one dask client for the grid)
    rays : rays per point; precision : or trace each point to this target (``rays`` is then unused)
    checkpoint : a :class:`straylight.checkpoints.PointStore` (None: no checkpoints)
    desc, unit : the progress bar's title and unit; keep_traces : keep each TraceResult (not with checkpoints)
    """
    points = list(points)
    if precision is None and (rays is None or isinstance(rays, bool) or int(rays) < 1):
        raise ValueError(f"rays must be >= 1, got {rays!r}")
    if keep_traces and checkpoint is not None:
        raise ValueError("checkpoints keep numbers, not traces: keep_traces cannot be combined with them")
    ex = as_execution(execution)
    out: list[PointRun] = []
    with ex.opened() as here, progress_bar(total=len(points), desc=desc, unit=unit, enabled=ex.progress) as bar:
        each = here.quiet()  # the grid's bar is the progress; no bar per trace
        for point in points:
            done = _restored(checkpoint, point)
            if done is None:
                bar.set_postfix_str(point.label)
                done = _trace_point(point, job(point), each, rays, precision, keep_traces,
                                    lambda msg, p=point: bar.set_postfix_str(f"{p.label}: {msg}"))
                if checkpoint is not None:
                    checkpoint.put(point.key, done.record(point.tag))
            out.append(done)
            bar.update(1)
    return out


def _trace_point(point: GridPoint, tj: TraceJob, execution: Execution, rays, precision, keep_traces,
                 tell) -> PointRun:
    """Trace one point (fixed rays or to the precision target) and keep its numbers."""
    t0 = time.perf_counter()
    if precision is None:
        res = trace(tj.scene, tj.sources, n_rays=int(rays), seed=point.seed, materials=tj.materials,
                    options=tj.options, execution=execution)
        diagnostics = _diagnostics(reliability(*res.chunks_of(tj.detector), res.n_rays))
    else:
        run = trace_to_precision(tj.scene, tj.sources, point.seed, precision, materials=tj.materials,
                                 options=tj.options, detectors=[tj.detector], on_round=tell, execution=execution)
        res = run.result
        diagnostics = {**_diagnostics(run.reliability[tj.detector]), "stop_reason": run.stop_reason,
                       "rounds": len(run.rounds)}
    seconds = time.perf_counter() - t0
    tally = res.detectors[tj.detector]
    values = tj.values(tally)
    rel_error = tally.stderr_w / tally.power_w if tally.power_w > 0 else math.nan
    if untrusted(diagnostics, rel_error):  # name the path that holds the variance (straylight.analyses.heaviest)
        diagnostics["heaviest_path"] = _heaviest(tj, point.seed, res)
    plan = getattr(res, "strategies", None)  # the strategies asked for that did not run, and why (pst.json)
    diagnostics["strategies_off"] = {} if plan is None else {name: why for name, why in plan.off}
    unscattered = getattr(res, "unscattered_w", None) or {}
    if tj.detector in unscattered:  # the straight light, computed exactly (direct_area): part of the point's power
        diagnostics["unscattered_w"] = unscattered[tj.detector]
    return PointRun(values, int(res.n_rays), seconds, diagnostics, res if keep_traces else None)


def _heaviest(tj: TraceJob, seed: int, res) -> dict | None:
    """:func:`straylight.analyses.heaviest.heaviest_path`; a failure of this diagnostic warns and keeps the
    point (its numbers are traced: nothing is lost for want of a label)."""
    try:
        return heaviest_path(tj, seed, res)
    except Exception as exc:  # noqa: BLE001 - a diagnostic must not cost the point
        warnings.warn(f"the heaviest path of {tj.detector!r} could not be named: {exc}", RuntimeWarning, stacklevel=2)
        return None


def precision_summary(precision: Precision | None) -> dict | None:
    """The target and caps as pst.json states them (None for a fixed ray count)."""
    if precision is None:
        return None
    return {"target_rel_error": precision.target_rel_error, "max_rays": int(precision.max_rays),
            "max_seconds": None if not math.isfinite(precision.max_seconds) else float(precision.max_seconds),
            "max_vov": precision.max_vov, "first_rays": int(precision.first_rays)}


def open_checkpoint(folder, fingerprint: dict, resume: bool = False):
    """The grid's :class:`straylight.checkpoints.PointStore` in ``folder`` for a run of this
    ``fingerprint`` (everything that decides its numbers), or None without a folder."""
    if folder is None:
        if resume:
            raise ValueError("resume needs a checkpoint folder")
        return None
    return PointStore(folder, fingerprint, resume=resume)
