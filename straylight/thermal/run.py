"""Detector self-emission in a band: the ``straylight thermal`` computation (CONTRACTS §7.1).

For each detector part: sub-bands (straylight.thermal.model.sub_bands), each traced at its own
wavelength with its own streams; the estimate is the sum over sub-bands of independent means, so
its variance is the sum of theirs. Rays go to sub-bands in proportion to the radiance of the
hottest part there. ``target_rel_error`` adds rounds of chunks until the relative standard error of
the detector power is at most the target (or ``max_rays`` / ``max_seconds`` stop it: reported in
``stopped``).

The rays are the engine's chunks (straylight.rng: CHUNK_RAYS rays, each chunk its own stream), traced
in batches of whole chunks (straylight.rng.BatchDraws); ``execution`` (straylight.execution.Execution)
runs a round's batches in this process, one after another or on the engine's shared thread pool
(:meth:`straylight.engine.runtime.Runtime.pool`), and sums them in chunk order: the same numbers
either way.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from straylight.engine.options import TraceError
from straylight.execution import Execution, as_execution
from straylight.rng import CHUNK_RAYS, BatchDraws, stream_chunk
from straylight.stop_rule import Precision, next_round_rays
from straylight.thermal.tables import plot_thermal, thermal_frame
from straylight.detectors import FRONT_FACE_COS, DetectorGeometry
from straylight.thermal.engine_forward import EngineForwardRun
from straylight.thermal.model import split_rays, sub_bands
from straylight.thermal.planck import band_radiance_w_m2_sr, check_band
from straylight.thermal.reverse import reverse_batch
from straylight.thermal.sampling import AreaSampler
from straylight.thermal.walk import batches_of, chunk_counts

METHODS = ("reverse", "forward")
DEFAULT_MAX_RAYS = 50_000_000
DEFAULT_MAX_SECONDS = 600.0
ZERO_POWER_RAYS = 100_000  # --target-rel-error gives up on a detector that nothing reaches after this
MIN_ROUND_RAYS = 512  # first round of --target-rel-error, and the smallest later round (per sub-band)
THERMAL_MIN_CHUNKS = 16  # no precision stop before this many chunks of rays (the VOV needs batches)


@dataclass
class Tally:
    power_w: float
    stderr_w: float


@dataclass
class DetectorThermal:
    name: str
    area_mm2: float
    power_w: float
    stderr_w: float
    by_part: dict  # part name -> Tally
    rays: int  # per detector (the most any detector used; --rays N: N)

    @property
    def irradiance_w_m2(self) -> float:
        return self.power_w / (self.area_mm2 * 1e-6)

    def to_json_dict(self) -> dict:
        """CONTRACTS §7.1's entry, exactly its keys."""
        return {"power_w": self.power_w, "stderr_w": self.stderr_w, "irradiance_w_m2": self.irradiance_w_m2,
                "by_part": {k: {"power_w": v.power_w, "stderr_w": v.stderr_w} for k, v in self.by_part.items()}}


@dataclass
class ThermalResult:
    band_um: tuple
    rays: int  # per detector: --rays N gives exactly N (the most any detector used with a target)
    seed: int
    method: str
    detectors: dict
    sub_bands: list
    temperatures_k: dict
    seconds: float
    stopped: str | None = None
    sweep: dict = field(default_factory=dict)  # detector -> [(power_w, stderr_w)] per extra temperature set

    def to_json_dict(self) -> dict:
        """thermal.json (CONTRACTS §7.1), exactly its keys; the rest is in :meth:`details`."""
        return {"band_um": [float(self.band_um[0]), float(self.band_um[1])], "rays": int(self.rays),
                "seed": int(self.seed), "detectors": {k: v.to_json_dict() for k, v in self.detectors.items()}}

    def to_pandas(self):
        """One row per (detector, emitting part): power and error (pandas is optional; straylight.thermal.tables)."""
        return thermal_frame(self)

    def plot(self, path=None, ax=None):
        """Bars of each emitting part's power on each detector, 1-sigma error bars (log scale)."""
        return plot_thermal(self, path, ax)

    def details(self) -> dict:
        """thermal_details.json: how the numbers were made (method, traced wavelengths, areas, time)."""
        out = {"method": self.method, "temperatures_k": self.temperatures_k,
               "sub_bands_um": [[a, b, c] for a, b, c in self.sub_bands], "seconds": self.seconds,
               "detectors": {k: {"area_mm2": v.area_mm2, "rays": v.rays,
                                 "irradiance_stderr_w_m2": v.stderr_w / (v.area_mm2 * 1e-6)}
                             for k, v in self.detectors.items()}}
        if self.stopped:
            out["stopped"] = self.stopped
        return out


def receiving_triangles(ts, p: int, toward_mm=None) -> np.ndarray:
    """Triangle ids of detector part ``p`` that receive (CONTRACTS 4.5 area rule): every triangle of an
    open part; a closed part's faces whose outward normal is within 60 deg of its front (the normal
    of its plane of least spread, turned toward ``toward_mm``: the scene's centre by default)."""
    ids = np.flatnonzero(ts.triangle_part == p)
    part = ts.scene.parts[p]
    if not part.meta.get("watertight", part.is_watertight):
        return ids
    geo = DetectorGeometry.from_triangles(ts.triangles_mm[ids])
    if toward_mm is None:
        others = ts.triangle_part != p
        pts = ts.triangles_mm[others].reshape(-1, 3) if others.any() else ts.triangles_mm.reshape(-1, 3)
        toward_mm = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    normal = geo.normal if float(np.dot(np.asarray(toward_mm) - geo.origin_mm, geo.normal)) >= 0 else -geo.normal
    front = ts.normals[ids] @ normal > FRONT_FACE_COS
    return ids[front] if front.any() else ids


def detector_sampler(ts, p: int, toward_mm=None):
    if p in ts.planes:
        return AreaSampler.of_part(ts, p), np.flatnonzero(ts.triangle_part == p)
    ids = receiving_triangles(ts, p, toward_mm)
    a = ts.areas_mm2[ids]
    return AreaSampler(ts.triangles_mm[ids], ts.normals[ids], float(a.sum()), np.cumsum(a) / a.sum()), ids


class _Sums:
    """Per-stream running sums of per-ray estimates (per part, and total per temperature set)."""

    def __init__(self, n_parts, n_sets=1):
        self.n = 0
        self.s1 = np.zeros(n_parts)
        self.s2 = np.zeros(n_parts)
        self.t1 = 0.0 if n_sets == 1 else np.zeros(n_sets)
        self.t2 = 0.0 if n_sets == 1 else np.zeros(n_sets)
        self.chunks: list = []  # (rays, sum, sum of squares) of the total (first set) per chunk: the VOV

    def add(self, n, s1, s2, t1, t2):
        self.chunks.append((n, float(np.atleast_1d(t1)[0]), float(np.atleast_1d(t2)[0])))
        self.n += n
        self.s1 += s1
        self.s2 += s2
        self.t1 += t1
        self.t2 += t2

    @staticmethod
    def _var(n, s1, s2):
        if n < 2:
            return np.full(np.shape(s1), np.inf)
        return np.maximum(s2 - s1 * s1 / n, 0.0) / (n * (n - 1.0))

    def means(self):
        return self.s1 / max(self.n, 1), self._var(self.n, self.s1, self.s2), self.t1 / max(self.n, 1), \
            self._var(self.n, self.t1, self.t2)


def thermal(ts, band_um, n_rays: int | None = None, target_rel_error: float | None = None, seed: int = 0,
            method: str = "reverse", detectors=None, max_rays: int = DEFAULT_MAX_RAYS,
            max_seconds: float = DEFAULT_MAX_SECONDS, toward_mm=None, sweep=None,
            execution: Execution | None = None) -> ThermalResult:
    """Band power from every part at a temperature reaching each detector (CONTRACTS §7.1).

    ``ts``: :class:`straylight.thermal.model.ThermalScene`. Give ``n_rays`` (per detector) or
    ``target_rel_error``. ``method``: "reverse" (default, rays from the detector) or "forward"
    (the parts' emission as engine sources, straylight.sources.SurfaceEmission, traced by the main
    engine's ``trace``: straylight.thermal.engine_forward). ``sweep``: further temperature sets
    ((P,) arrays, kelvin) evaluated on the same reverse paths (``ThermalResult.sweep``: per detector
    a list of (power, stderr)); the precision target applies to the scene's own temperatures.
    ``execution``: where the batches run (:class:`_Runner`); the numbers never depend on it."""
    runner = _Runner(as_execution(execution), ts)
    lo, hi = check_band(*band_um)
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    if (n_rays is None) == (target_rel_error is None):
        raise ValueError("give exactly one of --rays or --target-rel-error")
    if n_rays is not None and int(n_rays) < 2:
        raise ValueError(f"--rays must be >= 2, got {n_rays!r}")
    if target_rel_error is not None and not (0 < float(target_rel_error) < 1):
        raise ValueError(f"--target-rel-error must be in (0, 1), got {target_rel_error!r}")
    names = [n for n, r in zip(ts.part_names, ts.roles) if r == "detector"] if detectors is None else list(detectors)
    if not names:
        raise ValueError("the scene has no detector part (role = \"detector\")")
    bands = sub_bands(lo, hi, ts.wavelength_dependent())
    sets = [np.asarray(ts.temperature_k, float)] + [np.asarray(t, float) for t in (sweep or [])]
    if len(sets) > 1 and method != "reverse":
        raise ValueError("a temperature sweep needs the reverse method")
    t_all = np.array(sets)  # (C, P)
    rad_sets = np.array([np.where(t_all > 0, band_radiance_w_m2_sr(a, b, np.maximum(t_all, 1.0)), 0.0)
                         for a, b, _ in bands])  # (K, C, P)
    radiance = rad_sets[:, 0, :]  # (K, P): the scene's own temperatures
    emitting = [n for n, t in zip(ts.part_names, ts.temperature_k) if t > 0]
    t0 = time.perf_counter()
    out, stopped, max_rays_one, swept = {}, None, 0, {}
    share = rad_sets.max(axis=(1, 2)) if rad_sets.max() > 0 else np.ones(len(bands))
    share = share / share.sum()
    chunk_counter = [0]  # the next free engine chunk id of the forward run's traces
    for j, name in enumerate(names):
        p = ts.part_index(name)
        sampler, _ = detector_sampler(ts, p, toward_mm)
        min_rays = MIN_ROUND_RAYS if target_rel_error is not None else 2
        run: EngineForwardRun | _DetectorRun
        if method == "forward":  # the main engine's trace of the parts' emission (straylight.thermal.engine_forward)
            run = EngineForwardRun(ts, bands, rad_sets, share, ts.part_names[p], seed, min_rays, runner.threads,
                                   chunk_counter)
        else:
            run = _DetectorRun(ts, bands, rad_sets, share, _estimator(method, ts, p, sampler), seed,
                               (j * len(bands), len(names) * len(bands)), min_rays, runner)
        if rad_sets.max() <= 0:
            tot, err, per, per_err = 0.0, 0.0, np.zeros(ts.n_parts), np.zeros(ts.n_parts)
        elif n_rays is not None:
            run.round(int(n_rays))
            tot, err, per, per_err = run.combined()
        else:
            target = float(target_rel_error)  # type: ignore[arg-type]  # set when n_rays is None
            # the same rule as trace's and the PST's rounds (straylight.analyses.precision): the stop (the
            # error AND its reliability: VOV, no chunk dominating, a minimum sample of chunks, a confirming
            # look) and the size of the next round (straylight.stop_rule.next_round_rays)
            t_det = time.perf_counter()
            rule = Precision(target, max_rays=max(int(max_rays), CHUNK_RAYS), min_chunks=THERMAL_MIN_CHUNKS,
                             max_seconds=max(max_seconds - (t_det - t0), 1e-3))
            looks: list = []
            rays_now = MIN_ROUND_RAYS * len(bands)
            while True:
                run.round(rays_now)
                tot, err, per, per_err = run.combined()
                done = run.rays
                looks.append(run.look())
                if rule.stops(looks) or (radiance.max() <= 0 and done > 0):
                    break
                if tot <= 0 and done >= ZERO_POWER_RAYS:
                    stopped = f"no emission reached the detector in {done} rays: power 0"
                    break
                if done >= max_rays or time.perf_counter() - t0 > max_seconds:
                    stopped = (f"stopped at {done} rays / {time.perf_counter() - t0:.0f} s with relative error "
                               f"{err / tot if tot > 0 else float('inf'):.3g} (target {target_rel_error})")
                    break
                rays_now = min(next_round_rays(looks, rule, time.perf_counter() - t_det), max(int(max_rays) - done, 2))
        max_rays_one = max(max_rays_one, run.rays)
        by_part = {ts.part_names[q]: Tally(float(per[q]), float(per_err[q])) for q in range(ts.n_parts)
                   if ts.part_names[q] in emitting}
        out[name] = DetectorThermal(name, sampler.area_mm2, float(tot), float(err), by_part, run.rays)
        swept[name] = [run.combined(c)[:2] if rad_sets.max() > 0 and run.rays else (0.0, 0.0)
                       for c in range(1, len(sets))]
    runner.close()
    temps = {n: float(t) for n, t in zip(ts.part_names, ts.temperature_k) if t > 0}
    return ThermalResult((lo, hi), max_rays_one, int(seed), method, out, bands, temps,
                         time.perf_counter() - t0, stopped, sweep=swept)


class _DetectorRun:
    """The running sums of one detector's trace, sub-band by sub-band: sub-band k is the stream
    ``first_stream + k`` of the run's ``n_streams`` (straylight.rng.stream_chunk), its chunks the
    engine's (CHUNK_RAYS rays, each its own generator)."""

    def __init__(self, ts, bands, rad_sets, share, estimator, seed, streams, min_rays, runner):
        self.ts, self.bands, self.rad_sets, self.share = ts, bands, rad_sets, share
        self.estimator, self.seed, self.streams, self.min_rays = estimator, seed, streams, min_rays
        self.runner = runner
        self.sums = [_Sums(ts.n_parts, rad_sets.shape[1]) for _ in bands]
        self.next_chunk = [0] * len(bands)

    @property
    def rays(self) -> int:
        return sum(s.n for s in self.sums)

    def round(self, rays_now: int) -> None:
        """About ``rays_now`` more rays, shared by the sub-bands (whole chunks, then a remainder),
        traced in batches of whole chunks by the runner and summed chunk by chunk in chunk order."""
        active = np.array([self.rad_sets[k].max() > 0 for k in range(len(self.bands))])
        counts = split_rays(int(rays_now), np.where(active, self.share, 0.0), self.min_rays)
        tasks = []
        for k, (_, _, lam) in enumerate(self.bands):
            want = int(counts[k])
            if want <= 0:
                continue
            sides = self.ts.sides_at(lam)
            rad = self.rad_sets[k] if self.rad_sets.shape[1] > 1 else self.rad_sets[k, 0]
            sizes = chunk_counts(want)
            ids = [stream_chunk(self.next_chunk[k] + c, self.streams[0] + k, self.streams[1]) for c in range(len(sizes))]
            self.next_chunk[k] += len(sizes)
            tasks += [(k, sides, rad, b_ids, b_counts) for b_ids, b_counts in batches_of(ids, sizes)]
        one_set = self.rad_sets.shape[1] == 1
        for (k, _, _, _, b_counts), (s1, s2, t1, t2) in zip(tasks, self.runner.map(self._batch, tasks)):
            for j, m in enumerate(b_counts):
                self.sums[k].add(m, s1[:, j], s2[:, j], float(t1[0, j]) if one_set else t1[:, j],
                                 float(t2[0, j]) if one_set else t2[:, j])

    def _batch(self, task):
        """Per-chunk sums of one batch: per part (P, chunks) and totals (C, chunks), with their squares."""
        _, sides, rad, ids, counts = task
        draws = BatchDraws(self.seed, ids, counts)
        per, tot = self.estimator(sides, rad, draws)
        return (*draws.chunk_sums(per), *draws.chunk_sums(tot))

    def look(self):
        """The precision stop's view of the total (straylight.analyses.precision.Look): its relative error,
        and the VOV and largest chunk share of the sub-band that holds most of the variance."""
        from straylight.stop_rule import Look, reliability

        tot, err, _, _ = self.combined()
        worst, best_var = None, -1.0
        for s in self.sums:
            if s.n < 2 or not s.chunks:
                continue
            n_c, t1, t2 = (np.array(x, dtype=np.float64) for x in zip(*s.chunks))
            var = max(float(t2.sum()) - float(t1.sum()) ** 2 / s.n, 0.0) / (s.n * (s.n - 1.0))
            if var > best_var:
                best_var, worst = var, reliability(t1, t2, s.n, chunk_rays=n_c)
        chunks = sum(len(s.chunks) for s in self.sums)
        if worst is None or tot <= 0:
            return Look(self.rays, tot, float("nan"), float("nan"), float("nan"), chunks)
        return Look(self.rays, tot, err / tot, worst.vov, worst.max_chunk_share, chunks)

    def combined(self, c: int = 0):
        """(total, its stderr, per-part (P,), their stderrs) for temperature set ``c``: sums over
        the sub-bands' independent means."""
        means = [s.means() for s in self.sums]
        tot = sum(np.atleast_1d(m[2])[c] for m in means)
        var = sum(np.atleast_1d(m[3])[c] for m, s in zip(means, self.sums) if s.n > 0)
        per = sum(m[0] for m in means)
        per_var = sum(m[1] for m, s in zip(means, self.sums) if s.n > 0)
        return float(tot), float(np.sqrt(var)), per, np.sqrt(per_var)


def _estimator(method, ts, p, sampler):
    """batch function (sides, radiance (P,) or (C, P), draws) -> per-ray estimates (per part (P, n), totals (C, n))
    of the reverse estimator (the forward one is the engine's trace: straylight.thermal.engine_forward)."""
    return lambda sides, rad, draws: reverse_batch(ts, sides, sampler, rad, draws)


class _Runner:
    """Runs a round's batches where ``execution`` says, results in batch order (so the sums are the
    same whichever way they ran): in this process one after another, or on the engine's shared pool
    of ``threads`` threads (:meth:`straylight.engine.runtime.Runtime.pool`; embree and the compiled
    kernels release the GIL). ``workers`` K is K threads here: the thermal walks run in this process
    (the default local dask cluster is one process of K threads too); a dask ``client`` or
    ``scheduler`` is refused. Progress (``execution.progress``): chunks done, on stderr."""

    def __init__(self, execution: Execution, ts):
        if execution.client is not None or execution.scheduler is not None:
            raise TraceError("thermal runs in this process: give execution threads or workers, not a dask "
                             "client or scheduler")
        if execution.intersector is not None or execution.first_chunk:
            raise TraceError("thermal takes no execution intersector or first_chunk")
        self.threads = int(execution.threads or execution.workers or 1)
        self.ts = ts
        self.bar = None
        if execution.progress:
            from straylight.progress import progress_bar

            self.bar = progress_bar(unit="chunk", desc="thermal")

    def map(self, fn, tasks) -> list:
        if self.threads <= 1 or len(tasks) <= 1:
            return [self._done(fn(t), t) for t in tasks]
        from straylight.engine.runtime import runtime

        self._warm(tasks)
        pool = runtime().pool(self.threads)
        futures = [pool.submit(fn, t) for t in tasks]
        return [self._done(f.result(), t) for f, t in zip(futures, tasks)]

    def _warm(self, tasks) -> None:
        """Build what the threads share before they start: the embree scene, the materials' tables."""
        self.ts.intersector.first_triangle(np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]))
        for t in tasks:
            _ = t[1].material_index, t[1].models

    def _done(self, result, task):
        if self.bar is not None:
            self.bar.update(len(task[3]))
        return result

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
