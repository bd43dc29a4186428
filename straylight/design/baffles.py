"""``straylight design baffles`` end to end (CONTRACTS 8.2, docs/baffles.md).

1. :func:`straylight.design.telescope_model.identify` finds the primary, secondary and image by
   walking an on-axis fan through the exact surfaces (mirrors are parts with a ``specular`` material).
2. :func:`straylight.design.telescope_model.nominal_bundle` traces the edge rays of the field -F..F.
3. :func:`straylight.design.shields.candidates` builds the least-obscuring skirt + tube (+ collar and
   rear enclosure) that closes every straight line from the image to the sky, and a few wider-skirt or
   shorter-tube variants within the budget; :func:`refine` (``refine_rays`` > 0) traces them all with the
   scene's materials and common random numbers and keeps the lowest PST.
   When none fits the budget, :func:`with_sunshade` keeps the widest skirt that does and
   :mod:`straylight.design.sunshade` adds a sunshade in front that stops the steep lines it leaves open.
4. The designed scene is checked by the project's Monte Carlo tracer: with perfect mirrors and every
   other part an absorber (glass keeps refracting), the detector power from 2F to 10 deg must be 0
   (the *direct-path check*; before the shields it is usually not), and the throughput on axis and at
   F/3, 2F/3 and F is compared with the unshielded telescope's (:func:`field_check`).
5. The PST before and after with the scene's own materials, DIR/scene.toml, DIR/design.json,
   DIR/baffles.step (CadQuery solids, one per baffle, knife-edged tube), DIR/index.html + view.html.
"""
from __future__ import annotations

import math
import time
import tomllib
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

import atomicio

THROUGHPUT_KEPT = 0.95
PERFECT_MIRROR = {"name": "perfect_mirror", "wavelength_nm": 532.0, "components": [{"type": "specular", "r": 1.0}]}
ABSORBER = {"name": "absorber", "wavelength_nm": 532.0, "components": [{"type": "lambertian", "rd": 0.0}]}


def direct_angles(field_deg: float) -> list[float]:
    """The angles of the direct-path check: 2F to 10 deg (at least 2F), five steps."""
    lo = max(2.0 * field_deg, 1e-3)
    if lo >= 10.0:
        return [lo]
    return [float(a) for a in np.linspace(lo, 10.0, 5)]


def ideal_materials(setup):
    """Perfect mirrors (r = 1), glass as it is, everything else an absorber (rd = 0)."""
    from materials import load_material

    from straylight.design.telescope_model import _kind

    mirror, black = load_material(PERFECT_MIRROR), load_material(ABSORBER)
    out = dict(setup.materials)
    for p in setup.scene.parts:
        if p.material is None:
            continue
        kind = _kind(p, setup.materials)
        if kind == "mirror":
            out[p.material] = mirror
        elif kind != "glass":
            out[p.material] = black
        if p.back_material is not None and p.back_material != p.material and kind != "glass":
            out[p.back_material] = black
    return out


def _sweep(setup, angles_deg, rays, seed, nee=True):
    from straylight.analyses.pst import pst_sweep

    res = pst_sweep(setup, np.radians(angles_deg), n_rays=int(rays), seed=int(seed), nee=nee)
    return [{"off_axis_deg": float(a), "pst": float(p), "pst_stderr": float(e), "detector_w": float(w),
             "detector_stderr_w": float(we), "rays": int(rays)}
            for a, p, e, w, we in zip(angles_deg, res.pst, res.pst_stderr, res.detector_w, res.detector_stderr_w)]


def throughput_budget(obscuration_before: float, max_added: float) -> float:
    """The added obscuration a layout with a sunshade may spend: the allowed one, and no more than keeps
    ``THROUGHPUT_KEPT`` of the bare telescope's on-axis light (1 - after >= 0.95 (1 - before)), less
    0.005 for the trace's own error (a 20000-ray trace measures the ratio to about 0.002)."""
    return min(max_added, (1.0 - THROUGHPUT_KEPT) * (1.0 - obscuration_before)) - 5e-3


def with_sunshade(setup, tel, bundle, max_added, refusal, log):
    """The widest skirt within the budget (:func:`throughput_budget`) and a sunshade that stops the lines it
    leaves open (straylight.design.sunshade); raises ``refusal`` (the one line, with the shade's reason)
    when there is none."""
    from straylight.design import shields, sunshade

    budget = throughput_budget(shields.obscuration(tel, bundle, None), max_added)
    lay = shields.within_budget(tel, bundle, budget) if budget > 0 else None
    if lay is None:
        raise refusal
    try:
        shade = sunshade.construct(setup, tel, bundle, lay)
    except sunshade.SunshadeError as exc:
        raise shields.NoShieldError(f"{refusal}; the widest skirt within it needs {exc}") from None
    if shade is None:
        raise refusal
    lay.sunshade = shade
    closing = getattr(refusal, "smallest_added", None)
    log(f"the skirt and tube that close every direct path add {closing if closing is None else round(closing, 4)} "
        f"of the aperture: kept a skirt of {lay.skirt_radius_mm:.4g} mm (adds "
        f"{lay.obscuration_after - lay.obscuration_before:.4f}) and a sunshade of radius {shade.radius_mm:.4g} mm, "
        f"{shade.to_u - shade.from_u:.4g} mm long, that stops the lines it leaves open "
        f"({shade.angles_deg[0]:.2f}-{shade.angles_deg[1]:.2f} deg)")
    return lay


def critical_angles(layout, field_deg: float) -> list[float]:
    """Sky angles the direct-path check adds: where the lines the sunshade stops leave the telescope."""
    if layout.sunshade is None:
        return []
    lo, hi = layout.sunshade.angles_deg
    lo_ok = max(lo, 2.0 * field_deg)
    if hi < lo_ok or lo_ok > 10.0:
        return []
    return [float(a) for a in np.linspace(lo_ok, min(hi, 10.0), 3)]


def both_mirrors(events, primary: str, secondary: str) -> bool:
    """Whether a path's events hold a specular reflection on the primary followed by one on the secondary."""
    names = [p for p, k in events if k == "specular"]
    if primary not in names:
        return False
    return secondary in names[names.index(primary) + 1:]


def direct_check(setup, tel, angles_deg, rays, seed) -> list[dict]:
    """Per angle: the image's power from paths that did not reflect from the primary and then the
    secondary (``direct_w``, with its standard error), and its total power (``detector_w``), with
    ``ideal_materials`` and path records (straylight.paths)."""
    from straylight.analyses.grid import point_seed
    from straylight.trace import EstimatorOptions, OutputOptions, TraceOptions, trace

    opts = TraceOptions(estimator=EstimatorOptions(nee=False), output=OutputOptions(record_paths=True, path_depth=16))
    out = []
    for i, a in enumerate(angles_deg):
        res = trace(setup.scene, [setup.beam.source(math.radians(a))], int(rays), seed=point_seed(seed, i),
                    materials=setup.materials, options=opts)
        det = res.detectors[setup.detector]
        direct, err = 0.0, 0.0
        if res.paths is not None and len(res.paths):
            for g in res.paths.group(by=lambda ev, d: (d == setup.detector and
                                                        not both_mirrors(ev, tel.primary, tel.secondary))):
                if g.key:
                    direct, err = float(g.power_w), float(g.stderr_w)
        out.append({"off_axis_deg": float(a), "direct_w": direct, "direct_stderr_w": err,
                    "detector_w": float(det.power_w), "detector_stderr_w": float(det.stderr_w), "rays": int(rays)})
    return out


def field_check(before, after, field_deg: float, rays, seed) -> list[dict]:
    """Per angle F/3, 2F/3 and F: the image's power without and with the shields (``direct_check``'s
    materials and the same rays for both) and their ratio (None where the bare telescope puts nothing on
    the image): the shields must not vignette the field, so it stays close to the on-axis one."""
    from straylight.analyses.grid import point_seed
    from straylight.trace import EstimatorOptions, TraceOptions, trace

    if field_deg <= 0:
        return []
    opts = TraceOptions(estimator=EstimatorOptions(nee=False))
    out = []
    for i, angle in enumerate(field_deg * k / 3.0 for k in (1, 2, 3)):
        w = [trace(s.scene, [s.beam.source(math.radians(angle))], int(rays), seed=point_seed(seed, i),
                   materials=s.materials, options=opts).detectors[s.detector].power_w for s in (before, after)]
        out.append({"off_axis_deg": float(angle), "detector_w_before": float(w[0]), "detector_w_after": float(w[1]),
                    "throughput_ratio": float(w[1] / w[0]) if w[0] > 0 else None})
    return out


def output_scene_doc(scene_path: Path, parts: list[dict], upstream_of=None) -> dict:
    """The input scene's TOML with file paths made absolute (the output lives elsewhere) and the baffle
    parts appended (analytic surfaces, CONTRACTS 6.1)."""
    doc = tomllib.loads(scene_path.read_text())
    base = scene_path.parent.resolve()

    def fix(value):
        if isinstance(value, str) and not Path(value).is_absolute() and (base / value).exists():
            return str((base / value).resolve())
        return value

    for part in doc.get("part", []):
        for key in ("mesh", "material", "back_material"):
            if key in part:
                part[key] = fix(part[key])
    names = {p.get("name") for p in doc.get("part", [])}
    clash = sorted(names & {p["name"] for p in parts})
    if clash:
        raise ValueError(f"{scene_path}: the scene already has part(s) {', '.join(clash)}; "
                         "design baffles adds parts with these names (remove or rename them)")
    doc.setdefault("part", [])
    for p in parts:
        doc["part"].append({"name": p["name"], "surface": p["surface"], "material": p["material"], "role": "surface"})
    pts = [_baffle_points(parts)] if parts else []
    if upstream_of is not None:
        pts.append(np.atleast_2d(np.asarray(upstream_of, float)))
    if pts:
        move_sources_upstream(doc, np.concatenate(pts))
    return doc


def _baffle_points(parts: list[dict]) -> np.ndarray:
    """End points of every shield (both ends of a cylinder, the centre of an annulus), rims included."""
    pts = []
    for p in parts:
        s = p["surface"]
        v = np.asarray(s["vertex_mm"], float)
        pts.append(v)
        if s["type"] == "cylinder":
            pts.append(v + s["length_mm"] * np.asarray(s["axis"], float))
    return np.array(pts)


def move_sources_upstream(doc: dict, pts: np.ndarray, clearance_mm: float = 1.0) -> None:
    """Sources start where they are (they are virtual): a collimated source placed close to the secondary
    (``optics import`` puts it 1 mm before the first vertex) would start inside the secondary's skirt and
    its rays would skip the shield. Such a source is moved back along its direction until every shield
    lies downstream of it (its disk, radius and direction unchanged); ``pts`` (n, 3): what must be downstream."""
    for src in doc.get("source", []):
        if src.get("type") != "collimated_disk" or "direction" not in src or "center_mm" not in src:
            continue
        d = np.asarray(src["direction"], float)
        d = d / np.linalg.norm(d)
        c = np.asarray(src["center_mm"], float)
        lead = float(np.min((pts - c) @ d)) - clearance_mm
        if lead < 0:
            src["center_mm"] = [float(v) for v in c + lead * d]


def refine(scene_path, tel, layouts, material, field_deg, rays, seed, log, upstream_of=None):
    """Monte Carlo choice among the feasible layouts (all close every direct path within the budget):
    each is traced with the scene's materials at 2F, the middle of the check's range and 10 deg, with the
    same rays for every layout (common random numbers: one seed, the optimiser's own, so differences
    between layouts are not noise between draws); the objective is mean log10 PST - log10(1 - obscuration)
    (stray light against the on-axis light kept), lowest wins. Variants other than the construction must
    keep ``THROUGHPUT_KEPT`` of the bare telescope's on-axis throughput. Returns the layout and
    the table of what was tried."""
    import tempfile

    import tomli_w

    from straylight.analyses.scene_setup import scene_setup
    from straylight.design import shields
    from straylight.design.vanes import optimiser_seed

    angles = direct_angles(field_deg)
    angles = sorted({angles[1 if len(angles) > 2 else 0], angles[len(angles) // 2 + 1 if len(angles) > 2 else 0],
                     angles[-1]})  # past 2F, where the edge of the nominal image may still fall on the image
    # the variants may spend more of the budget, but keep 95 % of the bare telescope's on-axis throughput
    layouts = [layouts[0]] + [x for x in layouts[1:]
                              if (1 - x.obscuration_after) >= THROUGHPUT_KEPT * (1 - x.obscuration_before)]
    crn_seed = optimiser_seed(seed)
    rows = []
    with tempfile.TemporaryDirectory(prefix="straylight-baffles-") as tmp:
        for k, lay in enumerate(layouts):
            doc = output_scene_doc(Path(scene_path), shields.baffle_parts(tel, lay, material), upstream_of)
            path = Path(tmp) / f"candidate_{k}.toml"
            atomicio.write_text(path, tomli_w.dumps(doc))
            pts = _sweep(scene_setup(path), angles, rays, crn_seed)
            floor = min(p["pst"] for p in pts if p["pst"] > 0) if any(p["pst"] > 0 for p in pts) else 1e-30
            # signal to stray light: the PST (per unit beam irradiance) against the on-axis light kept
            obj = float(np.mean([math.log10(max(p["pst"], 0.1 * floor)) for p in pts])
                        - math.log10(1.0 - lay.obscuration_after))
            rows.append({"skirt_radius_mm": lay.skirt_radius_mm, "skirt_bottom_u_mm": lay.skirt_bottom_u,
                         "tube_radius_mm": lay.tube_radius_mm, "tube_top_u_mm": lay.tube_top_u,
                         "obscuration_added": lay.obscuration_after - lay.obscuration_before,
                         "objective": obj, "pst": pts})
    best = int(np.argmin([r["objective"] for r in rows]))
    for k, r in enumerate(rows):
        r["chosen"] = k == best
    log(f"refinement: {len(rows)} layouts traced ({rays} rays per angle, common random numbers); "
        f"chose #{best} (objective {rows[best]['objective']:.3f} vs construction {rows[0]['objective']:.3f})")
    return layouts[best], {"angles_deg": angles, "rays": int(rays), "seed": int(crn_seed), "layouts": rows,
                           "chosen": best}


def design_baffles(scene_path, field_deg: float, out, *, max_added_obscuration: float = 0.05,
                   material: str = "z302_sample_b", rays: int = 20_000, seed: int = 0, step: bool = True,
                   refine_rays: int = 0, log=print) -> dict:
    """Design the shields of the telescope in ``scene_path`` and write ``out`` (module docstring)."""
    import tomli_w

    from straylight.analyses.scene_setup import scene_setup
    from straylight.design import shields, telescope_model

    if not (0.0 <= field_deg < 10.0) or not math.isfinite(field_deg):
        raise ValueError(f"--field-deg must be in [0, 10) deg, got {field_deg}")
    if not (0.0 <= max_added_obscuration < 1.0):
        raise ValueError(f"--max-added-obscuration must be in [0, 1), got {max_added_obscuration}")
    t0 = time.perf_counter()
    scene_path = Path(scene_path)
    out = Path(out)
    given = scene_setup(scene_path)
    try:
        tel = telescope_model.identify(given)
    except telescope_model.TelescopeError as exc:
        raise telescope_model.TelescopeError(f"{scene_path}: {exc}") from None
    log(f"primary {tel.primary!r}, secondary {tel.secondary!r}, image {tel.image!r} "
        f"(aperture radius {tel.aperture_radius_mm:.4g} mm)")
    bundle = telescope_model.nominal_bundle(given, tel, field_deg)
    notes = []
    if bundle.off_detector:  # the shields are sized for the field's beam all the same (nominal_bundle)
        notes.append(f"the detector {tel.image!r} (radius {tel.image_radius_mm:.4g} mm) does not cover the field: "
                     f"the image of {field_deg:g} deg reaches {bundle.field_image_radius_mm:.4g} mm; the shields "
                     "pass the whole field's beam")
        warnings.warn(notes[-1], stacklevel=2)
    # the secondary's rim must be downstream of the source too, or rays would start behind the secondary
    rim = [tel.point(tel.secondary_rim_u, sgn * tel.secondary_outer_mm) for sgn in (-1.0, 1.0)]
    try:
        layouts = shields.candidates(tel, bundle, max_added_obscuration, n_radii=2 if refine_rays > 0 else 1,
                                     radius_step=0.01)
    except shields.NoShieldError as exc:  # the skirt within the budget and a sunshade, or the CLI's one line
        layouts = [with_sunshade(given, tel, bundle, max_added_obscuration, exc, log)]
    refinement = None
    layout = layouts[0]
    if refine_rays > 0 and len(layouts) > 1:
        layout, refinement = refine(scene_path, tel, layouts, material, field_deg, refine_rays, seed, log, rim)
    parts = shields.baffle_parts(tel, layout, material)
    out.mkdir(parents=True, exist_ok=True)
    atomicio.write_text(out / "scene_unshielded.toml", tomli_w.dumps(output_scene_doc(scene_path, [], rim)))
    before = scene_setup(out / "scene_unshielded.toml")
    doc = output_scene_doc(scene_path, parts, rim)
    moved = [{"from_mm": a.get("center_mm"), "to_mm": b.get("center_mm")}
             for a, b in zip(tomllib.loads(scene_path.read_text()).get("source", []), doc.get("source", []))
             if a.get("center_mm") != b.get("center_mm")]
    if moved:
        log(f"source moved upstream of the shields: {moved}")
    atomicio.write_text(out / "scene.toml", tomli_w.dumps(doc))
    after = scene_setup(out / "scene.toml")
    # 4. direct-path check by the tracer, before and after (and where the sunshade's lines leave)
    angles = direct_angles(field_deg)
    critical = critical_angles(layout, field_deg)
    angles = sorted(set(angles) | set(critical))
    ideal_b = replace(before, materials=ideal_materials(before))
    ideal_a = replace(after, materials=ideal_materials(after))
    direct_before = direct_check(ideal_b, tel, [0.0] + angles, rays, seed)
    direct_after = direct_check(ideal_a, tel, [0.0] + angles, rays, seed)
    on_b, on_a = direct_before[0]["detector_w"], direct_after[0]["detector_w"]
    throughput = on_a / on_b if on_b > 0 else None
    field_throughput = field_check(ideal_b, ideal_a, field_deg, rays, seed)
    # 5. PST with the scene's own materials
    pst_angles = sorted({0.0, float(field_deg), *angles})
    pst_before = _sweep(before, pst_angles, rays, seed)
    pst_after = _sweep(after, pst_angles, rays, seed)
    step_file = None
    if step:
        from straylight.design.baffle_cad import write_step

        step_file = write_step(out / "baffles.step", tel, parts)
    design = {
        "field_deg": float(field_deg),
        "obscuration_before": layout.obscuration_before,
        "obscuration_after": layout.obscuration_after,
        "obscuration_added": layout.obscuration_after - layout.obscuration_before,
        "max_added_obscuration": float(max_added_obscuration),
        "baffles": [{k: v for k, v in p.items() if k != "surface"} for p in parts],
        "telescope": tel.to_dict(),
        "direct_margin_mm": layout.direct_margin_mm,
        "sunshade": None if layout.sunshade is None else {
            "radius_mm": layout.sunshade.radius_mm, "length_mm": layout.sunshade.to_u - layout.sunshade.from_u,
            "stops_angles_deg": list(layout.sunshade.angles_deg), "lines": layout.sunshade.lines,
            "skirt_alone_leaves_open_mm": -layout.direct_margin_mm},
        "direct_check": {
            "method": "perfect mirrors (r = 1), glass as in the scene, every other part an absorber; direct_w: "
                      "the image's power from paths without a reflection on the primary followed by one on the "
                      "secondary (path records); detector_w: all of the image's power",
            "before": direct_before[1:], "after": direct_after[1:],
            "blocked": all(p["direct_w"] == 0.0 for p in direct_after[1:]),
            "critical_angles_deg": critical,
            "on_axis_before": direct_before[0], "on_axis_after": direct_after[0],
            "on_axis_throughput_ratio": throughput, "field": field_throughput},
        "field_image_radius_mm": bundle.field_image_radius_mm, "warnings": notes,
        "pst_before": pst_before, "pst_after": pst_after, "refinement": refinement,
        "material": material, "rays": int(rays), "seed": int(seed), "sources_moved": moved,
        "step": step_file.name if step_file else None,
        "seconds": time.perf_counter() - t0,
    }
    atomicio.write_json(out / "design.json", design)
    from straylight.design.baffle_report import write_report

    write_report(out, design, after, tel)
    return design
