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
from dataclasses import replace

import numpy as np

from straylight.analyses.estimators import estimator_options
from straylight.analyses.grid import GridPoint, TraceJob, open_checkpoint, point_seed, precision_summary, run_grid
from straylight.analyses.types import Beam, PstResult, Setup
from straylight.execution import Execution


def part_area_mm2(scene, name: str) -> float:
    """Total triangle area of part ``name``, mm^2."""
    part = scene.part(name)
    t = part.vertices_mm[part.faces]
    return float(0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1).sum())


NO_DETECTOR = ("the scene has no detector part: add one, e.g. the exact disk [[part]] name = \"detector\", "
               "role = \"detector\", surface = {type = \"plane\", vertex_mm = [X, Y, Z], axis = [NX, NY, NZ], "
               "outer_radius_mm = R} (docs/reference/scene.md; straylight geometry scene --detector-disk writes it), "
               "or mark a solid with [part.solids.\"NAME\"] role = \"detector\"")


def detector_name(scene, name: str | None = None) -> str:
    """``name`` if it is a detector part, or the scene's only detector."""
    detectors = [p.name for p in scene.parts if p.role == "detector"]
    if name is not None:
        from geometry.mesh import GeometryError

        try:  # a CAD solid answers to its product and instance names alike (CONTRACTS 6.2)
            name = scene.resolve(name) if hasattr(scene, "resolve") else name
        except GeometryError as exc:
            raise ValueError(f"detector {name!r}: {exc}; detectors: {', '.join(detectors) or 'none'}") from None
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


def sweep_diffraction(scene, wavelength_nm, options) -> dict | None:
    """What pst.json says about edge diffraction (CONTRACTS §6.5): None when no part diffracts."""
    from straylight.engine.diffraction import METHOD, diffracting_parts

    parts = [scene.parts[i].name for i in diffracting_parts(scene)]
    if not parts:
        return None
    on = options.physics.diffraction != "off"
    return {"on": on, "method": METHOD if on else None, "parts": parts, "wavelength_nm": wavelength_nm,
            "hurb_gamma": float(options.physics.hurb_gamma) if on else None,
            "band_wavelengths": float(options.physics.diffraction_band_wavelengths) if on else None}


def pst_options(nee: bool = True, options=None, materials=None):
    """The trace options of a PST point: ``options`` (default: the ``default`` estimator set,
    :mod:`straylight.analyses.estimators`, for the scene's ``materials``) with next-event estimation,
    and the vertex sampling that builds on it, on or off."""
    opts = options or estimator_options("default", materials=materials)
    est = opts.estimator
    return replace(opts, estimator=replace(est, nee=bool(nee),
                                           first_vertex_sampling=bool(nee) and est.first_vertex_sampling,
                                           second_vertex_sampling=bool(nee) and est.second_vertex_sampling))


def pst_job(setup: Setup, detector: str, area_mm2: float, off_axis: float, azimuth: float, options) -> TraceJob:
    """One PST point of a grid (:mod:`straylight.analyses.grid`): the setup's beam at this tilt. Its
    values: ``pst`` = (P_det / area) / E_in, ``entrance_ratio`` = P_det / P_entrance (NaN without an
    entrance), ``detector_w``, each with its standard error."""
    beam: Beam = setup.beam
    p_ent = setup.entrance.power_w(beam, off_axis, azimuth) if setup.entrance is not None else math.nan
    e_in = beam.irradiance_w_per_mm2(off_axis, azimuth)

    def values(tally) -> dict:
        return {"pst": tally.power_w / area_mm2 / e_in, "pst_stderr": tally.stderr_w / area_mm2 / e_in,
                "entrance_ratio": tally.power_w / p_ent, "entrance_ratio_stderr": tally.stderr_w / p_ent,
                "detector_w": tally.power_w, "detector_stderr_w": tally.stderr_w}

    return TraceJob(setup.scene, [beam.source(off_axis, azimuth)], setup.materials, options, detector, values)


def pst_sweep(setup: Setup, off_axis, azimuth=(0.0,), n_rays: int = 100_000, seed: int = 0, nee: bool = True,
              options=None, execution: Execution | None = None, keep_traces: bool = False, precision=None,
              checkpoint_dir=None, resume: bool = False) -> PstResult:
    """Trace a collimated beam at each (off-axis, azimuth) and return the PST with errors.

    Parameters
    ----------
    setup : :class:`straylight.analyses.types.Setup` (scene, materials, beam, entrance, detector)
    off_axis : (n,) float, radians; azimuth : (m,) float, radians (every pair is traced)
    n_rays : rays per point; seed : user seed (point i gets :func:`straylight.analyses.grid.point_seed`)
    nee : importance sampling toward the detector: the engine's next-event estimation (a
        shadow ray per scatter vertex, combined with BRDF sampling by multiple importance
        sampling); False traces the plain random walk (same expectation, larger variance)
    options : ``straylight.trace.TraceOptions`` to start from (``nee`` overrides its field)
    execution : :class:`straylight.execution.Execution`: where to run (one dask cluster for the whole
        sweep) and whether to show progress; default: this process, quiet
    precision : :class:`straylight.analyses.precision.Precision` or None. Given, each point is
        traced in growing rounds (its own seed's streams continued) until its relative standard
        error reaches the target with a reliable error estimate, or a cap; ``n_rays`` is then unused
    checkpoint_dir, resume : write each finished point there (straylight.checkpoints.PointStore);
        ``resume`` reads back the points a previous run of the same sweep finished and skips them
    """
    off_axis = np.atleast_1d(np.asarray(off_axis, dtype=np.float64))
    azimuth = np.atleast_1d(np.asarray(azimuth, dtype=np.float64))
    if np.any(~np.isfinite(off_axis)) or np.any(np.abs(off_axis) >= np.pi / 2):
        raise ValueError("off-axis angles must be finite and below 90 deg")
    if np.any(~np.isfinite(azimuth)):
        raise ValueError(f"azimuths must be finite, got {', '.join(f'{math.degrees(a):g}' for a in azimuth)} deg")
    if int(n_rays) < 1:
        raise ValueError(f"rays must be >= 1, got {n_rays!r}")
    det = detector_name(setup.scene, setup.detector)
    sens = detector_area(setup, det)
    area = sens.area_mm2
    opts = pst_options(nee, options, setup.materials)
    pairs = [(a, phi) for phi in azimuth for a in off_axis]
    if keep_traces and checkpoint_dir is not None:
        raise ValueError("checkpoints keep numbers, not traces: keep_traces cannot be combined with them")
    scene = setup.scene
    store = open_checkpoint(checkpoint_dir, {
        "triangles": scene.triangles_mm, "triangle_part": scene.triangle_part,
        "parts": [(p.name, p.role, p.material) for p in scene.parts], "materials": setup.materials,
        "beam": setup.beam, "entrance": setup.entrance, "pairs": pairs, "rays": int(n_rays), "seed": int(seed),
        "options": opts, "precision": precision, "detector": det, "area_mm2": area}, resume)
    points = [GridPoint(i, point_seed(seed, i), f"{math.degrees(a):g} deg") for i, (a, _) in enumerate(pairs)]
    runs = run_grid(points, lambda p: pst_job(setup, det, area, *pairs[p.key], opts), execution, rays=int(n_rays),
                    precision=precision, checkpoint=store, desc="PST sweep", unit="angle", keep_traces=keep_traces)

    def column(key):
        return np.array([r.values[key] for r in runs], dtype=np.float64)

    return PstResult(
        off_axis_deg=np.round(np.degrees([a for a, _ in pairs]), 9),
        azimuth_deg=np.round(np.degrees([phi for _, phi in pairs]), 9),
        pst=column("pst"), pst_stderr=column("pst_stderr"), entrance_ratio=column("entrance_ratio"),
        entrance_ratio_stderr=column("entrance_ratio_stderr"), detector_w=column("detector_w"),
        detector_stderr_w=column("detector_stderr_w"), seconds=np.array([r.seconds for r in runs]),
        rays=int(n_rays), seed=int(seed), nee=bool(nee), detector=det, detector_area_mm2=area,
        beam_power_w=float(setup.beam.power_w), description=setup.description,
        traces=[r.trace for r in runs] if keep_traces else [], detector_area_rule=sens.rule,
        point_rays=np.array([r.rays for r in runs], dtype=np.int64),
        diffraction=sweep_diffraction(setup.scene, getattr(setup.beam, "wavelength_nm", None), opts),
        diagnostics=[r.diagnostics for r in runs], precision=precision_summary(precision),
    )


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
