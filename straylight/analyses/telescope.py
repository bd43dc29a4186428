"""Stray-light study of the built-in Cassegrain (``straylight study --builtin cassegrain``).

Per off-axis angle, three traces with path records (same seed, next-event estimation on):

- **A, the telescope as built** (mirrors: aluminium + micro-roughness + IEST level-300 particles;
  black baffles, tube and vanes; an uncoated filter): the total PST and the split of the focal
  plane's power by path: *nominal* (the image: primary, secondary, filter), *ghost* (any other
  purely specular path: the filter's two-bounce ghosts...), *mirror scatter* (the first scatter on a
  mirror), *vanes* and *baffles and tube* (the first scatter on those parts), *direct* (no event,
  or straight through the filter);
- **B, particles only** (mirrors without roughness): its mirror scatter is the *contamination*;
- **C, roughness only** (mirrors without particles): its mirror scatter is the *micro-roughness*.

PST = (focal-plane power / detector area) / beam irradiance normal to the rays (CONTRACTS §4.5);
``pst_normalized`` divides it by the on-axis value, i.e. the focal-plane irradiance from an off-axis
source over that from the same source on axis, as telescope designers quote it. Every number has
its Monte Carlo standard error; contributions are per-ray exact (straylight.paths).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import atomicio
from straylight.analyses.ghosts import ghost_table
from straylight.execution import Execution, as_execution
from straylight.trace import EstimatorOptions, OutputOptions, TraceOptions, trace

CONTRIBUTIONS = ("nominal", "ghost", "mirror scatter", "vanes", "baffles and tube", "direct")
MIRRORS = ("primary", "secondary")


def cassegrain_setup(params=None, mirror_components=None, tolerance_mm: float = 0.02):
    """A :class:`straylight.analyses.types.Setup` of the built-in Cassegrain (with a 5-mm filter)."""
    from geometry.parts.cassegrain import (BLACK_MATERIAL, FILTER_MATERIAL, FILTER_MATERIAL_TABLE,
                                           MIRROR_MATERIAL, MIRROR_MATERIAL_TABLE, CassegrainParams,
                                           cassegrain_scene)
    from materials import load_material
    from straylight.analyses.types import Beam, Entrance, Setup

    p = params or CassegrainParams(filter_thickness_mm=5.0)
    table = dict(MIRROR_MATERIAL_TABLE)
    if mirror_components is not None:
        table["components"] = [c for c in MIRROR_MATERIAL_TABLE["components"] if c["type"] in mirror_components]
    mats = {MIRROR_MATERIAL: load_material(table), BLACK_MATERIAL: load_material(BLACK_MATERIAL),
            FILTER_MATERIAL: load_material(FILTER_MATERIAL_TABLE)}
    scene = cassegrain_scene(p, tolerance_mm=tolerance_mm)
    top = p.tube_front_mm
    beam = Beam(center_mm=np.array([0.0, 0.0, top + 10.0]), axis=np.array([0.0, 0.0, -1.0]),
                radius_mm=p.tube_radius_mm + 1.0,
                pivot_mm=np.array([0.0, 0.0, top]))
    entrance = Entrance(center_mm=np.array([0.0, 0.0, top]), radius_mm=p.tube_radius_mm,
                        normal=np.array([0.0, 0.0, 1.0]))
    desc = (f"Cassegrain D={2 * p.aperture_radius_mm:g} mm F/{p.focal_length_mm / (2 * p.aperture_radius_mm):g}, "
            f"{p.vane_count} vanes, mirrors {', '.join(c['type'] for c in table['components'])}")
    return Setup(scene, mats, beam, entrance, "focal_plane", desc, {f: getattr(p, f) for f in p.names()})


def classify(events, nominal=("primary", "secondary")) -> str:
    """The contribution a path belongs to (module docstring)."""
    if not events:
        return "direct"
    kinds = [k for _, k in events]
    if all(k == "specular" for k in kinds):
        parts = tuple(p for p, _ in events)
        core = tuple(p for p in parts if not p.startswith("filter"))
        n_filter = len(parts) - len(core)
        if not core and n_filter <= 2:
            return "direct"  # straight through the filter
        return "nominal" if core == tuple(nominal) and n_filter <= 2 else "ghost"
    first = next(p for p, k in events if k == "scatter")
    if first in MIRRORS:
        return "mirror scatter"
    if first.startswith("vane_"):
        return "vanes"
    return "baffles and tube"


def _split(res, detector: str) -> dict:
    """{contribution: (power_w, stderr_w)} from a trace's path records (per-ray exact errors)."""
    out = {c: (0.0, 0.0) for c in CONTRIBUTIONS}
    if res.paths is None or len(res.paths) == 0:
        return out
    for g in res.paths.group(by=lambda ev, det: classify(ev) if det == detector else None):
        if g.key is not None:
            out[g.key] = (g.power_w, g.stderr_w)
    return out


@dataclass
class TelescopeStudy:
    rays: int = 50_000
    seed: int = 0
    angles_deg: tuple = (0.0, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0)
    ghost_angle_deg: float = 0.0
    timings_s: dict = field(default_factory=dict)


def _trace(setup, angle, cfg, execution: Execution):
    opts = TraceOptions(estimator=EstimatorOptions(nee=True), output=OutputOptions(record_paths=True, path_depth=16))
    return trace(setup.scene, [setup.beam.source(math.radians(angle))], int(cfg.rays), seed=cfg.seed,
                 materials=setup.materials, options=opts, execution=execution)


def run_telescope_study(out_dir, cfg: TelescopeStudy | None = None, execution: Execution | None = None) -> dict:
    """Trace A, B, C at every angle, write DIR/results.json, pst.json, ghosts.md/json, pst.png and
    index.html; returns the results dict. ``execution``: where the traces run (one dask cluster for
    the study when it names workers or a scheduler); its ``progress`` prints a line per angle."""
    cfg = cfg or TelescopeStudy()
    with as_execution(execution).opened() as ex:
        return _telescope_study(out_dir, cfg, ex)


def _telescope_study(out_dir, cfg: TelescopeStudy, ex: Execution) -> dict:
    progress = ex.progress
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    setups = {"A": cassegrain_setup(), "B": cassegrain_setup(mirror_components=("specular", "particulate")),
              "C": cassegrain_setup(mirror_components=("specular", "k_correlation"))}
    setup = setups["A"]
    det = setup.detector
    area = _area(setup.scene.part(det))  # a one-sided plane disk: its triangles' area
    points = []
    ghosts = None
    for angle in cfg.angles_deg:
        t0 = time.perf_counter()
        E = setup.beam.irradiance_w_per_mm2(math.radians(angle))
        runs = {k: _trace(s, angle, cfg, ex.quiet()) for k, s in setups.items()}
        a = runs["A"]
        total = a.detectors[det]
        split = _split(a, det)
        contam = _split(runs["B"], det)["mirror scatter"]
        rough = _split(runs["C"], det)["mirror scatter"]

        def pst(pw):
            return pw / area / E

        point = {"off_axis_deg": angle, "pst": pst(total.power_w), "pst_stderr": pst(total.stderr_w),
                 "detector_w": total.power_w, "detector_stderr_w": total.stderr_w, "rays": cfg.rays,
                 "contributions": {c: {"pst": pst(v[0]), "pst_stderr": pst(v[1])} for c, v in split.items()}}
        point["contributions"]["contamination (particles)"] = {"pst": pst(contam[0]), "pst_stderr": pst(contam[1])}
        point["contributions"]["micro-roughness"] = {"pst": pst(rough[0]), "pst_stderr": pst(rough[1])}
        points.append(point)
        if angle == cfg.ghost_angle_deg:
            ghosts = ghost_table(a.paths, det, total.power_w)
        if progress:
            print(f"  {angle:5.1f} deg: PST {point['pst']:.3e} +- {point['pst_stderr']:.1e} "
                  f"({time.perf_counter() - t0:.1f} s)", flush=True)
    on_axis = next((p for p in points if p["off_axis_deg"] == 0.0), None)
    for p in points:
        if on_axis is not None and on_axis["pst"] > 0:
            p["pst_normalized"] = p["pst"] / on_axis["pst"]
            rel = math.hypot(p["pst_stderr"] / p["pst"] if p["pst"] > 0 else 0.0, on_axis["pst_stderr"] / on_axis["pst"])
            p["pst_normalized_stderr"] = p["pst_normalized"] * rel
    cfg.timings_s["total"] = time.perf_counter() - t_start
    results = {"instrument": setup.description, "detector": det, "detector_area_mm2": area, "seed": cfg.seed,
               "rays_per_trace": cfg.rays, "points": points,
               "ghosts": ghosts.to_json_dict() if ghosts is not None else None,
               "method": __doc__.strip(), "timings_s": cfg.timings_s}
    atomicio.write_json(out / "results.json", results)
    atomicio.write_json(out / "pst.json", {
        "detector": det, "detector_area_mm2": area,
        "points": [{k: v for k, v in p.items() if k != "contributions"} | {"azimuth_deg": 0.0} for p in points]})
    if ghosts is not None:
        ghosts.write(out)
    _plot(points, out / "pst.png", setup.description)
    _html(results, out / "index.html", ghosts)
    return results


def _area(part) -> float:
    tri = part.vertices_mm[part.faces]
    return float(0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum())


def _plot(points, path, title):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    ang = np.array([p["off_axis_deg"] for p in points])
    keep = ang > 0
    names = ["total", "micro-roughness", "contamination (particles)", "ghost", "vanes", "baffles and tube", "direct"]
    for name in names:
        if name == "total":
            y = np.array([p["pst"] for p in points])
            e = np.array([p["pst_stderr"] for p in points])
        else:
            y = np.array([p["contributions"][name]["pst"] for p in points])
            e = np.array([p["contributions"][name]["pst_stderr"] for p in points])
        ok = keep & (y > 0)
        if ok.any():
            ax.errorbar(ang[ok], y[ok], yerr=e[ok], marker="o", ms=3, capsize=2, label=name,
                        lw=2 if name == "total" else 1)
    ax.set_yscale("log")
    ax.set_xscale("log")
    ax.set_xlabel("off-axis angle (deg)")
    ax.set_ylabel("PST")
    ax.set_title(title, fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    atomicio.write_figure(fig, path, dpi=120)
    plt.close(fig)


def _html(results, path, ghosts):
    cols = ["micro-roughness", "contamination (particles)", "ghost", "vanes", "baffles and tube", "direct", "nominal"]
    head = "".join(f"<th>{c}</th>" for c in ["angle (deg)", "PST", "PST / PST(0)"] + cols)
    rows = []
    for p in results["points"]:
        cells = [f"{p['off_axis_deg']:g}", f"{p['pst']:.3e} &plusmn; {p['pst_stderr']:.1e}",
                 f"{p.get('pst_normalized', float('nan')):.3e}"]
        cells += [f"{p['contributions'][c]['pst']:.2e} &plusmn; {p['contributions'][c]['pst_stderr']:.1e}" for c in cols]
        rows.append("<tr>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    ghost_html = ""
    if ghosts is not None:
        g_rows = "".join(f"<tr><td>{r.rank}</td><td>{r.kind}</td><td>{r.surfaces}</td><td>{r.sequence}</td>"
                         f"<td>{r.fraction:.3e}</td><td>{r.power_w:.3e} &plusmn; {r.stderr_w:.1e}</td></tr>"
                         for r in ghosts.rows[:15])
        ghost_html = (f"<h2>Specular paths and ghosts at {results['points'][0]['off_axis_deg']:g} deg</h2>"
                      "<table border=1 cellpadding=3><tr><th>rank</th><th>kind</th><th>surfaces</th><th>sequence</th>"
                      f"<th>fraction</th><th>power (W)</th></tr>{g_rows}</table>")
    html = (f"<html><head><meta charset='utf-8'><title>Cassegrain stray-light study</title></head><body>"
            f"<h1>Cassegrain stray-light study</h1><p>{results['instrument']}; {results['rays_per_trace']} rays per "
            f"trace, seed {results['seed']}; detector {results['detector']} ({results['detector_area_mm2']:.1f} mm^2)</p>"
            f"<img src='pst.png' width='70%'><h2>PST and its contributions</h2>"
            f"<table border=1 cellpadding=3><tr>{head}</tr>{''.join(rows)}</table>{ghost_html}"
            f"<h2>Method</h2><pre>{results['method']}</pre></body></html>")
    atomicio.write_text(path, html)
