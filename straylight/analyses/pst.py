"""Point source transmittance (PST) of an instrument over off-axis angles.

A collimated beam (a point source at infinity) is tilted by ``a`` off the instrument
axis (and turned by an azimuth ``phi`` about it) and traced; for each tilt two
normalisations are reported, both with Monte Carlo standard errors:

``pst``
    detector irradiance / input irradiance: ``(P_det / A_det) / E_in``, with ``E_in``
    the beam irradiance on a plane normal to the rays (Breault's definition; the
    usual "PST" of stray-light literature).
``entrance_ratio``
    detector power / power crossing the entrance disk: ``P_det / P_ent``
    (``shared/BENCHMARK.md``'s ``ratio(a)``). Needs an :class:`Entrance`.

Both are linear in ``P_det``, so their relative errors are those of the detector
tally. Each tilt is traced with its own seed, derived from ``seed`` and the tilt's
index, so the points are independent and the sweep is reproducible.
"""
from __future__ import annotations

import math
import time
from contextlib import contextmanager

import numpy as np

from straylight.analyses.types import Beam, PstResult, Setup
from straylight.execution import Execution
from straylight.progress import progress_bar


def point_seed(seed: int, index: int) -> int:
    """Seed of the ``index``-th point of a sweep: independent streams from one user seed."""
    return int(np.random.SeedSequence([int(seed), int(index)]).generate_state(1)[0])


def part_area_mm2(scene, name: str) -> float:
    """Total triangle area of part ``name``, mm^2."""
    part = scene.part(name)
    t = part.vertices_mm[part.faces]
    return float(0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1).sum())


NO_DETECTOR = ("the scene has no detector part: add one, e.g. the exact disk [[part]] name = \"detector\", "
               "role = \"detector\", surface = {type = \"plane\", vertex_mm = [X, Y, Z], axis = [NX, NY, NZ], "
               "outer_radius_mm = R} (CONTRACTS 6.4; `straylight geometry scene --detector-disk` writes it), "
               "or mark a solid with [part.solids.\"NAME\"] role = \"detector\"")


def detector_name(scene, name: str | None = None) -> str:
    """``name`` if it is a detector part, or the scene's only detector."""
    detectors = [p.name for p in scene.parts if p.role == "detector"]
    if name is not None:
        if name not in detectors:
            raise ValueError(f"detector {name!r} is not a detector part; detectors: {', '.join(detectors) or 'none'}")
        return name
    if not detectors:
        raise ValueError(NO_DETECTOR)
    if len(detectors) != 1:
        raise ValueError(f"the scene has {len(detectors)} detector parts ({', '.join(detectors)}); "
                         "name one with [analysis] detector = \"NAME\" or --detector")
    return detectors[0]


def detector_area(setup, name: str):
    """The detector area a PST divides by (:class:`straylight.detectors.SensitiveArea`).

    ``setup.detector_area_mm2`` when given ([analysis] detector_area_mm2); otherwise the part's
    sensitive area (:func:`straylight.detectors.sensitive_area`), its front turned toward the
    entrance centre (or the beam's disk centre without an entrance).
    """
    from geometry.analytic import Plane
    from straylight.detectors import SensitiveArea, sensitive_area

    part = setup.scene.part(name)
    if setup.detector_area_mm2 is not None:
        total = part_area_mm2(setup.scene, name)
        return SensitiveArea(float(setup.detector_area_mm2), total, False, "given: [analysis] detector_area_mm2")
    if isinstance(part.surface, Plane):
        return SensitiveArea(part.surface.area_mm2, part.surface.area_mm2, False,
                             "analytic plane: pi (outer^2 - inner^2), exact")
    toward = setup.entrance.center_mm if setup.entrance is not None else setup.beam.center_mm
    return sensitive_area(part.vertices_mm, part.faces, toward_mm=toward)


def dask_client(workers: int | None = None, scheduler: str | None = None, security=None):
    """A dask client for a whole sweep (one local cluster, not one per trace), or None in-process:
    :func:`straylight.engine.backends.dask.dask_client` (the one builder; 1 worker = this process)."""
    from straylight.engine.backends.dask import dask_client as one_builder

    return one_builder(workers, scheduler, security=security, in_process_below=2)


def sweep_diffraction(scene, wavelength_nm, options) -> dict | None:
    """What pst.json says about edge diffraction (CONTRACTS §6.5): None when no part diffracts."""
    from straylight.engine.diffraction import METHOD, diffracting_parts

    parts = [scene.parts[i].name for i in diffracting_parts(scene)]
    if not parts:
        return None
    on = options.diffraction != "off"
    return {"on": on, "method": METHOD if on else None, "parts": parts, "wavelength_nm": wavelength_nm,
            "hurb_gamma": float(options.hurb_gamma) if on else None,
            "band_wavelengths": float(options.diffraction_band_wavelengths) if on else None}


def pst_sweep(setup: Setup, off_axis, azimuth=(0.0,), n_rays: int = 100_000, seed: int = 0, nee: bool = True,
              options=None, workers: int | None = None, scheduler: str | None = None, client=None,
              progress: bool = True, keep_traces: bool = False, precision=None, checkpoint_dir=None,
              resume: bool = False, execution: Execution | None = None) -> PstResult:
    """Trace a collimated beam at each (off-axis, azimuth) and return the PST with errors.

    Parameters
    ----------
    setup : :class:`straylight.analyses.types.Setup` (scene, materials, beam, entrance, detector)
    off_axis : (n,) float, radians; azimuth : (m,) float, radians (every pair is traced)
    n_rays : rays per point; seed : user seed (each point gets :func:`point_seed`)
    nee : importance sampling toward the detector: the engine's next-event estimation (a
        shadow ray per scatter vertex, combined with BRDF sampling by multiple importance
        sampling); False traces the plain random walk (same expectation, larger variance)
    options : ``straylight.trace.TraceOptions`` to start from (``nee`` overrides its field)
    workers, scheduler, client : distribution (one dask cluster for the whole sweep)
    precision : :class:`straylight.analyses.precision.Precision` or None. Given, each point is
        traced in growing rounds (its own seed's streams continued) until its relative standard
        error reaches the target with a reliable error estimate, or a cap; ``n_rays`` is then unused
    checkpoint_dir, resume : write each finished point there (straylight.checkpoints.PointStore);
        ``resume`` reads back the points a previous run of the same sweep finished and skips them
    execution : :class:`straylight.execution.Execution`, optional: workers, scheduler, client and
        security in one object (the keywords are the same fields); given, its ``progress`` decides
    """
    from dataclasses import replace as dc_replace

    from straylight.analyses.estimators import estimator_options
    from straylight.analyses.precision import reliability, trace_to_precision
    from straylight.trace import trace

    off_axis = np.atleast_1d(np.asarray(off_axis, dtype=np.float64))
    azimuth = np.atleast_1d(np.asarray(azimuth, dtype=np.float64))
    if np.any(~np.isfinite(off_axis)) or np.any(np.abs(off_axis) >= np.pi / 2):
        raise ValueError("off-axis angles must be finite and below 90 deg")
    if int(n_rays) < 1:
        raise ValueError(f"rays must be >= 1, got {n_rays!r}")
    det = detector_name(setup.scene, setup.detector)
    sens = detector_area(setup, det)
    area = sens.area_mm2
    opts = options or estimator_options("default")
    opts = dc_replace(opts, nee=bool(nee), first_vertex_sampling=bool(nee) and opts.first_vertex_sampling,
                      second_vertex_sampling=bool(nee) and opts.second_vertex_sampling)
    pairs = [(a, phi) for phi in azimuth for a in off_axis]
    n = len(pairs)
    out = {k: np.full(n, np.nan) for k in ("pst", "pst_se", "ratio", "ratio_se", "p", "p_se", "sec")}
    point_rays = np.full(n, int(n_rays), dtype=np.int64)
    diagnostics = []
    traces = []
    store = _point_store(checkpoint_dir, resume, keep_traces, setup, pairs, n_rays, seed, opts, precision, det, area)
    ex = Execution.merged(execution, workers=workers, scheduler=scheduler, client=client)
    if execution is not None:
        progress = ex.progress
    with (dask_client(ex.workers, ex.scheduler, ex.security) if ex.client is None else _given(ex.client)) as cl:
        bar = progress_bar(pairs, desc="PST sweep", unit="angle", enabled=progress)
        for i, (a, phi) in enumerate(bar):
            bar.set_postfix_str(f"{math.degrees(a):g} deg")
            saved = store.get(i) if store is not None else None
            if saved is not None:  # finished by an earlier run of this sweep
                for k in out:
                    out[k][i] = saved[k]
                point_rays[i] = saved["rays"]
                diagnostics.append(saved["diagnostics"])
                continue
            beam: Beam = setup.beam
            p_ent = setup.entrance.power_w(beam, a, phi) if setup.entrance is not None else math.nan
            t0 = time.perf_counter()
            if precision is None:
                res = trace(setup.scene, [beam.source(a, phi)], n_rays=int(n_rays), seed=point_seed(seed, i),
                            materials=setup.materials, options=opts, client=cl)
                rel = reliability(*res.detector_chunks[det], res.n_rays)
                diagnostics.append({**_diag(rel)})
            else:
                run = trace_to_precision(setup.scene, [beam.source(a, phi)], point_seed(seed, i), precision,
                                         materials=setup.materials, options=opts, detectors=[det], client=cl,
                                         progress=lambda msg, a=a: bar.set_postfix_str(f"{math.degrees(a):g} deg: {msg}"))
                res = run.result
                point_rays[i] = res.n_rays
                diagnostics.append({**_diag(run.reliability[det]), "stop_reason": run.stop_reason,
                                    "rounds": len(run.rounds)})
            out["sec"][i] = time.perf_counter() - t0
            tally = res.detectors[det]
            e_in = beam.irradiance_w_per_mm2(a, phi)
            out["p"][i], out["p_se"][i] = tally.power_w, tally.stderr_w
            out["pst"][i] = tally.power_w / area / e_in
            out["pst_se"][i] = tally.stderr_w / area / e_in
            out["ratio"][i] = tally.power_w / p_ent
            out["ratio_se"][i] = tally.stderr_w / p_ent
            if keep_traces:
                traces.append(res)
            if store is not None:
                store.put(i, {**{k: float(out[k][i]) for k in out}, "rays": int(point_rays[i]),
                              "diagnostics": diagnostics[-1]})
    return PstResult(
        off_axis_deg=np.round(np.degrees([a for a, _ in pairs]), 9),
        azimuth_deg=np.round(np.degrees([phi for _, phi in pairs]), 9),
        pst=out["pst"], pst_stderr=out["pst_se"], entrance_ratio=out["ratio"], entrance_ratio_stderr=out["ratio_se"],
        detector_w=out["p"], detector_stderr_w=out["p_se"], seconds=out["sec"], rays=int(n_rays), seed=int(seed),
        nee=bool(nee), detector=det, detector_area_mm2=area, beam_power_w=float(setup.beam.power_w),
        description=setup.description, traces=traces, detector_area_rule=sens.rule, point_rays=point_rays,
        diffraction=sweep_diffraction(setup.scene, getattr(setup.beam, "wavelength_nm", None), opts),
        diagnostics=diagnostics, precision=None if precision is None else {
            "target_rel_error": precision.target_rel_error, "max_rays": int(precision.max_rays),
            "max_seconds": None if not math.isfinite(precision.max_seconds) else float(precision.max_seconds),
            "max_vov": precision.max_vov, "first_rays": int(precision.first_rays)},
    )


def _point_store(folder, resume, keep_traces, setup, pairs, n_rays, seed, opts, precision, det, area):
    """The sweep's :class:`straylight.checkpoints.PointStore` in ``folder`` (None: no checkpoints)."""
    if folder is None:
        if resume:
            raise ValueError("resume needs a checkpoint folder")
        return None
    if keep_traces:
        raise ValueError("checkpoints keep numbers, not traces: keep_traces cannot be combined with them")
    from straylight.checkpoints import PointStore

    scene = setup.scene
    fingerprint = {"triangles": scene.triangles_mm, "triangle_part": scene.triangle_part,
                   "parts": [(p.name, p.role, p.material) for p in scene.parts], "materials": setup.materials,
                   "beam": setup.beam, "entrance": setup.entrance, "pairs": pairs, "rays": int(n_rays),
                   "seed": int(seed), "options": opts, "precision": precision, "detector": det, "area_mm2": area}
    return PointStore(folder, fingerprint, resume=resume)


def _diag(rel) -> dict:
    d = rel.to_dict()
    return {"vov": d["vov"], "rel_error_of_error": d["rel_error_of_error"], "max_chunk_share": d["max_chunk_share"]}


@contextmanager
def _given(client):
    yield client


def geometric_direct_ratio(off_axis, r_entrance_mm: float, r_stop_mm: float, height_mm: float) -> np.ndarray:
    """Unvignetted direct transmission of a black tube: entrance disk -> stop disk.

    Area of the lens where the entrance disk (radius R), projected along the rays onto the
    stop plane (shifted by s = h tan a), overlaps the stop disk (radius r), divided by the
    entrance area pi R^2 (circle-circle intersection area; e.g. Weisstein, "Circle-Circle
    Intersection", MathWorld). Valid when the wall does not vignette (a straight cylinder
    with R >= r never does: both ends of a ray lie inside it).
    """
    s = np.abs(height_mm * np.tan(np.atleast_1d(np.asarray(off_axis, dtype=np.float64))))
    big, small = float(r_entrance_mm), float(r_stop_mm)
    out = np.zeros_like(s)
    inside = s <= abs(big - small)
    out[inside] = np.pi * min(big, small) ** 2
    part = (s > abs(big - small)) & (s < big + small)
    d = s[part]
    a1 = small**2 * np.arccos(np.clip((d**2 + small**2 - big**2) / (2 * d * small), -1, 1))
    a2 = big**2 * np.arccos(np.clip((d**2 + big**2 - small**2) / (2 * d * big), -1, 1))
    a3 = 0.5 * np.sqrt(np.maximum(0.0, (-d + small + big) * (d + small - big) * (d - small + big) * (d + small + big)))
    out[part] = a1 + a2 - a3
    return out / (np.pi * big**2)
