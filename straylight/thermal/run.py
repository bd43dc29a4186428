"""Detector self-emission in a band: the ``straylight thermal`` computation (CONTRACTS §7.1).

For each detector part: sub-bands (straylight.thermal.model.sub_bands), each traced at its own
wavelength with its own streams; the estimate is the sum over sub-bands of independent means, so
its variance is the sum of theirs. Rays go to sub-bands in proportion to the radiance of the
hottest part there. ``target_rel_error`` adds rounds of chunks until the relative standard error of
the detector power is at most the target (or ``max_rays`` / ``max_seconds`` stop it: reported in
``stopped``).

The reverse method (the default) needs emitters that its detector's rays can meet: when the emitting
sides are small against the detector's front (:func:`reverse_suits`), or when it finds no emission at
all, the detector is traced with the forward method instead, and the result says so (``notes``,
thermal_details.json, and a :class:`MethodSwitchWarning`).

The rays are the engine's chunks (straylight.rng: CHUNK_RAYS rays, each chunk its own stream), traced
in batches of whole chunks (straylight.rng.BatchDraws); ``execution`` (straylight.execution.Execution)
runs a round's batches in this process, one after another or on the engine's shared thread pool
(:meth:`straylight.engine.runtime.Runtime.pool`), and sums them in chunk order: the same numbers
either way.
"""
from __future__ import annotations

import time
import warnings
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
# The reverse method needs emitters its detector's rays can meet: with the emitting area A_e (at the
# brightest side's radiance, :func:`emitting_area_mm2`) below this fraction of the detector's front A_d,
# at most about A_e / A_d of its rays pick up emission directly (etendue: a side of area A takes at
# most pi A of it) and its relative variance per ray grows as A_d / A_e, while the forward method's falls
# as A_e / A_d (reciprocity). Below 0.1 forward is the better by more than ten times in variance.
REVERSE_MIN_AREA_RATIO = 0.1


class MethodSwitchWarning(UserWarning):
    """The reverse method cannot serve a detector: it was traced with the forward method."""


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
    method: str = ""  # the method that traced it ("reverse" or "forward": the reverse one may hand over)

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
    notes: list = field(default_factory=list)  # why a detector was traced with another method than asked

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
               "detectors": {k: {"area_mm2": v.area_mm2, "rays": v.rays, "method": v.method or self.method,
                                 "irradiance_stderr_w_m2": v.stderr_w / (v.area_mm2 * 1e-6)}
                             for k, v in self.detectors.items()}}
        if self.stopped:
            out["stopped"] = self.stopped
        if self.notes:
            out["notes"] = list(self.notes)
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
    out, stopped, max_rays_one, swept, notes = {}, None, 0, {}, []
    share = rad_sets.max(axis=(1, 2)) if rad_sets.max() > 0 else np.ones(len(bands))
    share = share / share.sum()
    chunk_counter = [0]  # the next free engine chunk id of the forward run's traces
    area_e = emitting_area_mm2(ts, bands, radiance) if method == "reverse" and radiance.max() > 0 else 0.0
    for j, name in enumerate(names):
        p = ts.part_index(name)
        sampler, _ = detector_sampler(ts, p, toward_mm)
        min_rays = MIN_ROUND_RAYS if target_rel_error is not None else 2

        def new_run(how, p=p, j=j, sampler=sampler, min_rays=min_rays):
            if how == "forward":  # the main engine's trace of the parts' emission (straylight.thermal.engine_forward)
                return EngineForwardRun(ts, bands, rad_sets, share, ts.part_names[p], seed, min_rays, runner.threads,
                                        chunk_counter)
            return _DetectorRun(ts, bands, rad_sets, share, _estimator(how, ts, p, sampler), seed,
                                (j * len(bands), len(names) * len(bands)), min_rays, runner)

        use = method
        if method == "reverse" and radiance.max() > 0 and not reverse_suits(area_e, sampler.area_mm2):
            notes.append(_note(_too_small_note(name, sampler.area_mm2, area_e, sweep=len(sets) > 1)))
            use = "forward" if len(sets) == 1 else "reverse"  # a sweep needs the reverse paths
        if rad_sets.max() <= 0:
            run = new_run(use)
            tot, err, per, per_err = 0.0, 0.0, np.zeros(ts.n_parts), np.zeros(ts.n_parts)
        else:
            rounds = _Rounds(n_rays, target_rel_error, max_rays, max_seconds, t0, len(bands), radiance.max() > 0)
            use, run, (tot, err, per, per_err), stopped_j = _measure(new_run, use, name, rounds,
                                                                     may_switch=len(sets) == 1, notes=notes)
            stopped = stopped_j or stopped
        max_rays_one = max(max_rays_one, run.rays)
        by_part = {ts.part_names[q]: Tally(float(per[q]), float(per_err[q])) for q in range(ts.n_parts)
                   if ts.part_names[q] in emitting}
        out[name] = DetectorThermal(name, sampler.area_mm2, float(tot), float(err), by_part, run.rays, use)
        swept[name] = [run.combined(c)[:2] if rad_sets.max() > 0 and run.rays else (0.0, 0.0)
                       for c in range(1, len(sets))]
    runner.close()
    temps = {n: float(t) for n, t in zip(ts.part_names, ts.temperature_k) if t > 0}
    used = {d.method for d in out.values()}
    return ThermalResult((lo, hi), max_rays_one, int(seed), used.pop() if len(used) == 1 else method, out, bands,
                         temps, time.perf_counter() - t0, stopped, sweep=swept, notes=notes)


_ZERO = "zero"  # _Rounds' stop when no emission reached the detector in ZERO_POWER_RAYS rays


def _measure(new_run, use, name, rounds, may_switch, notes):
    """One detector's estimate with the method ``use`` (``new_run(method)`` makes its run). A reverse
    run that finds no emission at all is traced again forward when ``may_switch`` (a true zero, or
    emitters its rays missed; a note in ``notes``). Returns (the method used, its run, ``run.combined()``,
    why it stopped early: None or a sentence)."""
    run = new_run(use)
    stop, combined = rounds.run(run)
    if combined[0] <= 0 and use == "reverse" and may_switch:
        notes.append(_note(_zero_note(name, run.rays)))
        use, run = "forward", new_run("forward")
        stop, combined = rounds.run(run)
    if stop is _ZERO:
        stop = f"no emission reached the detector in {run.rays} rays: power 0"
    return use, run, combined, stop


@dataclass
class _Rounds:
    """How a detector's run is traced: ``n_rays`` rays at once, or rounds to ``target`` (relative error)."""

    n_rays: int | None
    target: float | None
    max_rays: int
    max_seconds: float
    t0: float  # the start of the whole run (max_seconds counts from it)
    n_bands: int
    emits: bool  # some part has band radiance (else one round of nothing)

    def run(self, run):
        """(why it stopped early: None, :data:`_ZERO` or a sentence; ``run.combined()``)."""
        if self.n_rays is not None:
            run.round(int(self.n_rays))
            return None, run.combined()
        return _to_target(run, float(self.target), self.max_rays, self.max_seconds, self.t0,
                          self.n_bands, self.emits)


def _to_target(run, target, max_rays, max_seconds, t0, n_bands, emits):
    """Rounds of ``run`` until the precision rule stops (straylight.stop_rule, the same rule as trace's and
    the PST's rounds: the error AND its reliability: VOV, no chunk dominating, a minimum sample of
    chunks, a confirming look; the size of the next round by ``next_round_rays``), or a cap does.
    Returns (why it stopped early: None, :data:`_ZERO` or a sentence; ``run.combined()``)."""
    t_det = time.perf_counter()
    rule = Precision(target, max_rays=max(int(max_rays), CHUNK_RAYS), min_chunks=THERMAL_MIN_CHUNKS,
                     max_seconds=max(max_seconds - (t_det - t0), 1e-3))
    looks: list = []
    rays_now = MIN_ROUND_RAYS * n_bands
    while True:
        run.round(rays_now)
        tot, err, per, per_err = combined = run.combined()
        done = run.rays
        looks.append(run.look())
        if rule.stops(looks) or (not emits and done > 0):
            return None, combined
        if tot <= 0 and done >= ZERO_POWER_RAYS:
            return _ZERO, combined
        if done >= max_rays or time.perf_counter() - t0 > max_seconds:
            return (f"stopped at {done} rays / {time.perf_counter() - t0:.0f} s with relative error "
                    f"{err / tot if tot > 0 else float('inf'):.3g} (target {target})"), combined
        rays_now = min(next_round_rays(looks, rule, time.perf_counter() - t_det), max(int(max_rays) - done, 2))


def emitting_area_mm2(ts, bands, radiance) -> float:
    """A_e = sum_s A_s L_s / max_s L_s over the emitting sides s (every part's front, and the back of a
    one-sided part: model.ThermalScene.one_sided), with L_s = sum_k eps_h,k(s) B_band,k(T) the side's
    band radiance over the sub-bands k (``radiance`` (K, P), W m^-2 sr^-1): the area that, at the
    brightest side's radiance, would emit what all of them emit (mm^2)."""
    area, lum = [], []
    for p in np.flatnonzero(np.asarray(radiance).max(axis=0) > 0):
        for side in (0, 1) if ts.one_sided[p] else (0,):
            L = sum(float(radiance[k, p]) * ts.sides_at(lam).hemispherical(int(p), side)
                    for k, (_, _, lam) in enumerate(bands))
            if L > 0:
                area.append(ts.part_area_mm2(int(p)))
                lum.append(L)
    if not lum:
        return 0.0
    return float(np.dot(area, lum) / max(lum))


def reverse_suits(area_e_mm2: float, detector_area_mm2: float) -> bool:
    """Whether the reverse method can serve a detector of front ``detector_area_mm2`` in a scene of
    emitting area ``area_e_mm2`` (:func:`emitting_area_mm2`): A_e >= REVERSE_MIN_AREA_RATIO A_d."""
    return area_e_mm2 >= REVERSE_MIN_AREA_RATIO * detector_area_mm2


def _too_small_note(name, detector_area_mm2, area_e_mm2, sweep: bool) -> str:
    what = ("kept for the temperature sweep (it needs the reverse paths): its estimate and error may be "
            "unreliable; check with --method forward without the sweep") if sweep else \
        "traced with the forward method instead"
    return (f"detector {name!r}: the reverse method cannot serve it: the emitting area ({area_e_mm2:.4g} mm^2 at "
            f"the brightest side's radiance) is {area_e_mm2 / detector_area_mm2:.3g} of its front "
            f"({detector_area_mm2:.4g} mm^2), below {REVERSE_MIN_AREA_RATIO:g}, so its rays would rarely meet "
            f"an emitter; {what}")


def _zero_note(name, rays) -> str:
    return (f"detector {name!r}: the reverse method found no emission in {rays} rays; traced with the forward "
            f"method, which tells a true zero from emitters the reverse rays missed")


def _note(text: str) -> str:
    """``text``, also given as a :class:`MethodSwitchWarning` (one line on the command line)."""
    warnings.warn(text, MethodSwitchWarning, stacklevel=3)
    return text


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
