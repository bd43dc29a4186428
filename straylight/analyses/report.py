"""The stray-light study: every analysis of an instrument, written as a report folder.

``run_study(out_dir)`` builds the default baffled tube (the BENCHMARK.md geometry, walls
and vanes coated with the ``z302_sample_b`` preset) -- or loads the user's scene file or
parametric model (``StudyConfig.scene`` / ``.model``), whose report then speaks of its own parts
and materials -- then

1. a PST sweep over off-axis angles (next-event estimation toward the detector);
2. a design sweep of the vane count (0..9) at two stray-light angles (the built-in tube, or a
   model's own parameter; a scene file has none);
3. the stray-light path report at one stray-light angle;
4. critical and illuminated objects at that angle;
5. a 3-D view with traced rays, a view coloured by absorbed power, and the detector map,

and writes PNG plots, CSV/JSON results, ``report.md`` and ``index.html`` into ``out_dir``.
Every Monte Carlo number carries its standard error; each step has its own seed derived
from the user's seed.
"""
from __future__ import annotations

import html
import json
import math
import platform
import re
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

import atomicio
from straylight.analyses.grid import point_seed
from straylight.execution import Execution, as_execution

if TYPE_CHECKING:
    from straylight.stop_rule import Precision

DEFAULT_ANGLES_DEG = (0.0, 2.0, 5.0, 8.0, 10.0, 12.0, 14.0, 16.0, 20.0, 25.0, 30.0, 40.0, 50.0, 60.0)
DEFAULT_SWEEP_ANGLES_DEG = (20.0, 30.0)
DEFAULT_PATH_ANGLE_DEG = 20.0


@dataclass
class StudyConfig:
    """What the study runs; ``rays`` is the PST rays per angle, other steps scale from it."""

    rays: int = 200_000
    seed: int = 0
    material: str = "z302_sample_b"
    angles_deg: tuple = DEFAULT_ANGLES_DEG
    sweep_parameter: str = "vane_count"
    sweep_values: tuple = tuple(range(10))
    sweep_angles_deg: tuple = DEFAULT_SWEEP_ANGLES_DEG
    path_angle_deg: float = DEFAULT_PATH_ANGLE_DEG
    scene: str | None = None  # SCENE.toml: the user's instrument instead of the built-in tube
    detector: str | None = None  # overrides the scene's [analysis] detector
    sweep: bool = True  # the design sweep (built-in tube parameters, or a --model file's)
    precision: Precision | None = None  # PST points traced to a target
    model: str | None = None  # FILE.py:build, the user's parametric CadQuery design (analyses.model)
    thermal_band_um: tuple = (8.0, 12.0)  # self-emission budget band when parts have temperature_k

    @property
    def sweep_rays(self) -> int:
        return max(1000, self.rays // 2)

    @property
    def path_rays(self) -> int:
        return max(1000, 2 * self.rays)

    @property
    def critical_rays(self) -> int:
        return max(1000, self.rays)


@dataclass
class StudyResult:
    out_dir: Path
    config: StudyConfig
    files: dict = field(default_factory=dict)
    timings_s: dict = field(default_factory=dict)
    summary: dict = field(default_factory=dict)


def _step(name: str, progress: bool):
    if progress:
        print(f"[study] {name} ...", file=sys.stderr, flush=True)


def benchmark_direct_ratio(off_axis, params: dict) -> np.ndarray:
    """Unscattered transmission of the built-in tube (entrance normalisation), BENCHMARK.md formula.

    With equal vane holes and detector radius, the direct beam is limited by the top vane's
    hole (top face at z_top) and the detector: lens(r, r, z_top tan a) / (pi r_entrance^2).
    Returns NaN where that shortcut does not hold (no vanes, or unequal radii).
    """
    from straylight.analyses.pst import geometric_direct_ratio

    if not params or "vane_inner_radius_mm" not in params:  # a scene file: no formula
        return np.full(np.shape(off_axis), np.nan)
    r_v, r_e = params["vane_inner_radius_mm"], params["inner_radius_mm"]
    r_d = params["detector_radius_mm"] or params["field_stop_radius_mm"]
    if params["vane_count"] < 1 or not math.isclose(r_v, r_d) or params["field_stop_radius_mm"] < r_v:
        return np.full(np.shape(off_axis), np.nan)
    z_top = params["vane_last_z_mm"] + params["vane_thickness_mm"] / 2 if params["vane_z_mm"] is None \
        else max(params["vane_z_mm"]) + params["vane_thickness_mm"] / 2
    return geometric_direct_ratio(off_axis, r_v, r_d, z_top) * (r_v / r_e) ** 2


def unscattered_share(pst) -> np.ndarray:
    """Per point, the share of its detector power that the tracer computed as straight light (direct_area:
    pst.json's ``unscattered_w`` over ``detector_w``); NaN where it did not."""
    out = np.full(len(pst.pst), np.nan)
    for i, row in enumerate(pst.rows()):
        w = row.get("unscattered_w")
        if w is not None and pst.detector_w[i] > 0:
            out[i] = w / pst.detector_w[i]
    return out


def unscattered_ratio(pst, formula) -> np.ndarray:
    """Per point, the unscattered light / entrance power: as computed exactly by the tracer where it was
    (:func:`unscattered_share` times the point's detector / entrance ratio), else ``formula``
    (:func:`benchmark_direct_ratio`'s, NaN for a scene file)."""
    computed = unscattered_share(pst)[:len(formula)] * pst.entrance_ratio[:len(formula)]
    return np.where(np.isfinite(computed), computed, np.asarray(formula, dtype=np.float64))


POINTS_DIR = "study.points"  # finished sweep points of an unfinished study (straylight.checkpoints)


def run_study(out_dir, config: StudyConfig | None = None, resume: bool = False,
              execution: Execution | None = None) -> StudyResult:
    """Run every step and write the report folder; returns what was written and the key numbers.

    ``execution``: where every step runs (one dask cluster for the whole study when it names workers
    or a scheduler) and whether to show progress (:class:`straylight.execution.Execution`).

    Each finished point of the PST and design sweeps is kept in ``out_dir/study.points`` until the
    report is written; ``resume`` reads those back instead of tracing them again (same numbers).
    On Ctrl-C (KeyboardInterrupt) a partial ``results.json``/``index.html`` naming the finished and
    missing steps is written before the interrupt is passed on."""
    cfg = config or StudyConfig()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    done: list[str] = []
    try:
        return _run_study(out, cfg, resume, done, as_execution(execution))
    except KeyboardInterrupt:
        write_partial_report(out, cfg, done)
        raise


def planned_steps(cfg: StudyConfig) -> list[str]:
    """The study's steps, in order, for this configuration."""
    sweep = cfg.sweep and ((cfg.model is not None and cfg.sweep_values) or (cfg.scene is None and cfg.model is None))
    return ["geometry", "pst", "paths", "critical", *(["sweep"] if sweep else []), "views", "report"]


def write_partial_report(out: Path, cfg: StudyConfig, done: list[str]) -> None:
    """results.json and index.html of an interrupted study: which steps finished, which are missing."""
    missing = [s for s in planned_steps(cfg) if s not in done]
    points = {p.name: len(list(p.glob("point_*.json"))) for p in sorted((out / POINTS_DIR).glob("*"))
              if p.is_dir() and p.name != "study"}
    files = sorted(p.name for p in out.iterdir() if p.is_file() and p.name not in ("results.json", "index.html")
                   and not p.name.startswith("."))
    doc = {"status": "interrupted", "completed_steps": list(done), "missing_steps": missing,
           "finished_sweep_points": points, "files": files,
           "resume": "run the same study command again with --resume: finished sweep points are read back",
           "config": _config_dict(cfg)}
    atomicio.write_json(out / "results.json", doc)
    items = "".join(f'<li><a href="{html.escape(f)}">{html.escape(f)}</a></li>' for f in files)
    pts = "".join(f"<li>{html.escape(k)}: {v} points</li>" for k, v in points.items())
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>Interrupted study</title></head>
<body style="font-family: sans-serif; max-width: 900px; margin: 2em auto">
<h1>{html.escape(_title(StudyResult(out, cfg)))}: interrupted</h1>
<p>Finished steps: {html.escape(', '.join(done) or 'none')}.</p>
<p><strong>Missing steps: {html.escape(', '.join(missing))}.</strong></p>
<p>Sweep points finished and kept for <code>--resume</code>:</p><ul>{pts or '<li>none</li>'}</ul>
<p>Run the same <code>straylight study</code> command again with <code>--resume</code> to finish it;
the finished sweep points are read back, not traced again.</p>
<h2>Files written so far</h2><ul>{items or '<li>none</li>'}</ul>
</body></html>
"""
    atomicio.write_text(out / "index.html", page)


def _config_dict(cfg: StudyConfig) -> dict:
    return {k: (list(v) if isinstance(v, tuple) else dict(v.__dict__) if k == "precision" and v else v)
            for k, v in cfg.__dict__.items()}


def _run_study(out: Path, cfg: StudyConfig, resume: bool, done: list, ex: Execution) -> StudyResult:
    with ex.opened() as here:  # one cluster (or none) for every step
        return _study_steps(out, cfg, resume, done, here)


def _study_steps(out: Path, cfg: StudyConfig, resume: bool, done: list, ex: Execution) -> StudyResult:
    from straylight import viz
    from straylight.analyses.builtin import tube_setup
    from straylight.analyses.critical import critical_objects
    from straylight.analyses.paths_report import paths_analysis
    from straylight.analyses.pst import pst_sweep
    from straylight.analyses.sweep import design_sweep

    from straylight.checkpoints import PointStore

    progress = ex.progress

    points = out / POINTS_DIR
    if not resume:
        PointStore.remove_folder(points)
    # settings first: a resume with other settings is refused before any work (the sweeps' own stores
    # check the scene and everything else that decides their numbers)
    PointStore(points / "study", _config_dict(cfg), resume=resume)
    result = StudyResult(out, cfg)
    t_all = time.perf_counter()

    t0 = time.perf_counter()
    if cfg.model is not None:
        from straylight.analyses.model import design_scene
        from straylight.analyses.scene_setup import scene_setup

        _step(f"building {cfg.model} with its default parameters", progress)
        scene_file: Path | str = design_scene(cfg.model, {}, out / "model_scene")
        setup = scene_setup(scene_file, detector=cfg.detector)
    elif cfg.scene is not None:
        from straylight.analyses.scene_setup import scene_setup

        _step(f"loading {cfg.scene}", progress)
        scene_file = cfg.scene
        setup = scene_setup(scene_file, detector=cfg.detector)
    else:
        _step("building the tube (CadQuery, tessellation)", progress)
        setup = tube_setup(material=cfg.material)
    result.timings_s["geometry"] = time.perf_counter() - t0
    done.append("geometry")

    each = (f"{cfg.rays} rays" if cfg.precision is None else
            f"to {cfg.precision.target_rel_error:.0%} rel. error"
            + (f" (at most {cfg.precision.max_seconds:g} s)" if cfg.precision.max_seconds < float("inf") else ""))
    _step(f"PST sweep, {len(cfg.angles_deg)} angles, each {each}", progress)
    t0 = time.perf_counter()
    pst = pst_sweep(setup, np.radians(cfg.angles_deg), n_rays=cfg.rays, seed=point_seed(cfg.seed, 1),
                    precision=cfg.precision, execution=ex, checkpoint_dir=points / "pst", resume=resume)
    result.timings_s["pst"] = time.perf_counter() - t0
    pst.write_csv(out / "pst.csv")
    pst.write_json(out / "pst.json")
    _pst_plot(pst, setup, out / "pst.png", cfg.material)
    pst.plot(out / "entrance_ratio.png", quantity="entrance_ratio")
    done.append("pst")

    _step(f"paths at {cfg.path_angle_deg:g} deg, {cfg.path_rays} rays", progress)
    t0 = time.perf_counter()
    report, trace_res = paths_analysis(setup, math.radians(cfg.path_angle_deg), n_rays=cfg.path_rays,
                                       seed=point_seed(cfg.seed, 2), execution=ex)
    result.timings_s["paths"] = time.perf_counter() - t0
    atomicio.write_text(out / "paths.md", report.markdown(20))
    report.write_csv(out / "paths.csv")
    report.write_json(out / "paths.json")
    report.plot(out / "paths.png", top=15)
    viz.plot_detector_map(trace_res.maps[setup.detector], out / "detector_map.png",
                          title=f"Detector irradiance at {cfg.path_angle_deg:g} deg off axis "
                                f"({cfg.path_rays:.2g} rays, 1 W beam)", rebin=4)
    done.append("paths")

    _step(f"critical and illuminated objects at {cfg.path_angle_deg:g} deg", progress)
    t0 = time.perf_counter()
    crit = critical_objects(setup, math.radians(cfg.path_angle_deg), n_rays=cfg.critical_rays,
                            seed=point_seed(cfg.seed, 3), execution=ex.quiet())
    result.timings_s["critical"] = time.perf_counter() - t0
    crit.write_json(out / "critical.json")
    crit.write_csv(out / "critical.csv")
    atomicio.write_text(out / "critical.md", crit.markdown())
    crit.plot(out / "critical.png")
    done.append("critical")

    from straylight.thermal.report import has_temperatures, thermal_step

    if has_temperatures(setup.scene):  # parts at a temperature: the self-emission budget
        _step(f"self-emission budget, {cfg.thermal_band_um[0]:g}-{cfg.thermal_band_um[1]:g} um", progress)
        t0 = time.perf_counter()
        thermal_step(setup, out, cfg.thermal_band_um, seed=point_seed(cfg.seed, 7))
        result.timings_s["thermal"] = time.perf_counter() - t0
        done.append("thermal")

    ghosts_doc = None
    if cfg.scene is not None or cfg.model is not None:  # a lens or window: its ghost table (the built-ins have none)
        from straylight.analyses.ghost_study import ghost_step, has_lenses

        if has_lenses(setup.materials):
            _step("ghost table on axis (order 2)", progress)
            t0 = time.perf_counter()
            ghosts_doc = ghost_step(scene_file, setup, out, seed=point_seed(cfg.seed, 8))
            result.timings_s["ghosts"] = time.perf_counter() - t0
            done.append("ghosts")

    sweep = None
    if cfg.sweep and cfg.model is not None and cfg.sweep_values:
        from straylight.analyses.model import model_sweep

        _step(f"design sweep of {cfg.model}: {cfg.sweep_parameter} over {list(cfg.sweep_values)}", progress)
        t0 = time.perf_counter()
        sweep = model_sweep(cfg.model, cfg.sweep_parameter, cfg.sweep_values, np.radians(cfg.sweep_angles_deg),
                            out / "designs", n_rays=cfg.sweep_rays, seed=point_seed(cfg.seed, 4),
                            execution=ex, checkpoint_dir=points / "sweep", resume=resume)
        result.timings_s["sweep"] = time.perf_counter() - t0
        sweep.write_csv(out / "sweep.csv")
        sweep.write_json(out / "sweep.json")
        sweep.plot(out / "sweep.png")
        done.append("sweep")
    elif cfg.sweep and cfg.scene is None and cfg.model is None:
        _step(f"design sweep of {cfg.sweep_parameter} over {list(cfg.sweep_values)}", progress)
        t0 = time.perf_counter()
        sweep = design_sweep(cfg.sweep_parameter, cfg.sweep_values, np.radians(cfg.sweep_angles_deg),
                             n_rays=cfg.sweep_rays, seed=point_seed(cfg.seed, 4), material=cfg.material,
                             execution=ex, checkpoint_dir=points / "sweep", resume=resume)
        result.timings_s["sweep"] = time.perf_counter() - t0
        sweep.write_csv(out / "sweep.csv")
        sweep.write_json(out / "sweep.json")
        sweep.plot(out / "sweep.png")
        done.append("sweep")

    _step("3-D views", progress)
    t0 = time.perf_counter()
    a = math.radians(cfg.path_angle_deg)
    walks = viz.trace_ray_paths(setup, a, n_rays=4000, seed=point_seed(cfg.seed, 5))
    hits = [w for w in walks if w[2]][:40]
    others = [w for w in walks if not w[2]][:160]
    viz.render_scene(setup.scene, out / "view_rays.png", ray_paths=others + hits,
                     title=f"{_short_name(setup)}, beam {cfg.path_angle_deg:g} deg off axis: {len(others) + len(hits)} "
                           f"rays ({len(hits)} reaching the detector, red)")
    viz.render_scene(setup.scene, out / "view_absorbed.png", color_by="absorbed",
                     absorbed_w={k: v.power_w for k, v in trace_res.absorbed.items()},
                     title=f"Absorbed power per part (detector in yellow), beam {cfg.path_angle_deg:g} deg off axis")
    from straylight import view3d  # the interactive view: parts, entrance, the ranked paths' sample rays

    view3d.write_view3d(out / "view3d.html", setup, trace_res, report, a, seed=point_seed(cfg.seed, 6),
                        title=f"{_short_name(setup)}, beam {cfg.path_angle_deg:g} deg off axis")
    result.timings_s["views"] = time.perf_counter() - t0
    done.append("views")
    result.timings_s["total"] = time.perf_counter() - t_all

    direct = unscattered_ratio(pst, benchmark_direct_ratio(np.radians(cfg.angles_deg), setup.params))
    result.summary = {
        "description": setup.description,
        "instrument": instrument_summary(setup, pst.detector_area_mm2),
        "pst": pst.to_json_dict(),
        "geometric_direct_entrance_ratio": [None if not np.isfinite(x) else float(x) for x in direct],
        "paths": report.to_json_dict(top=20),
        "critical": crit.to_json_dict(),
        "sweep": sweep.to_json_dict() if sweep is not None else None,
        "sweep_best": {f"{a:g} deg": sweep.best(j) for j, a in enumerate(sweep.off_axis_deg)} if sweep else None,
        "energy_ledger_at_path_angle": {"emitted_w": trace_res.emitted_w,
                                        "detected_w": sum(t.power_w for t in trace_res.detectors.values()),
                                        "absorbed_w": sum(t.power_w for t in trace_res.absorbed.values()),
                                        "escaped_w": trace_res.escaped.power_w},
        "thermal": json.loads((out / "thermal.json").read_text()) if "thermal" in done else None,
        "ghosts": ghosts_doc,
        "timings_s": result.timings_s,
        "config": _config_dict(cfg),
        "execution": ex.describe(),
        "software": {"python": platform.python_version(), "numpy": np.__version__},
    }
    atomicio.write_json(out / "results.json", result.summary)
    from straylight.analyses.tables import write_report_tables

    write_report_tables(out, pst, report, crit, sweep, direct)  # the report's tables as table_<name>.csv
    write_markdown(result, pst, report, crit, sweep, direct)
    write_html(result, pst, report, crit, sweep, direct)
    PointStore.remove_folder(points)  # the report holds every number now
    done.append("report")
    result.files = {p.name: p for p in sorted(out.iterdir()) if not p.name.startswith(".")}
    return result


def instrument_summary(setup, detector_area_mm2: float) -> dict:
    """The instrument as the report describes it: its parts (role, material, triangles) and detector."""
    from geometry.analytic import Plane

    parts = [{"name": p.name, "role": p.role, "material": p.material, "triangles": p.n_triangles,
              "analytic": None if p.surface is None else p.surface.kind} for p in setup.scene.parts]
    det = setup.scene.part(setup.detector)
    exact = isinstance(det.surface, Plane)
    return {"parts": parts, "detector": setup.detector, "detector_area_mm2": float(detector_area_mm2),
            "detector_shape": (f"exact disk, outer radius {det.surface.outer_radius_mm:g} mm"
                               + (f", inner {det.surface.inner_radius_mm:g} mm" if det.surface.inner_radius_mm else "")
                               if exact else f"mesh of {det.n_triangles} triangles")}


def _instrument_lines(result: StudyResult) -> list[str]:
    """What the instrument is made of: one line per material (its parts), and the detector."""
    cfg = result.config
    inst = result.summary.get("instrument")
    if cfg.scene is None and cfg.model is None or inst is None:
        return [f"- Coating: `{cfg.material}` on wall, vanes and end plate; the detector absorbs everything."]
    by_material: dict = {}
    for p in inst["parts"]:
        if p["role"] == "surface":
            by_material.setdefault(p["material"], []).append(p["name"])
    lines = []
    for material, names in sorted(by_material.items(), key=lambda kv: str(kv[0])):
        shown = ", ".join(names[:8]) + (f" and {len(names) - 8} more" if len(names) > 8 else "")
        lines.append(f"- Material `{material}` on {len(names)} part{'s' if len(names) > 1 else ''}: {shown}.")
    for role, what in (("mirror", "mirrors (specular, the trace's mirror reflectance)"),
                       ("absorber", "perfect absorbers")):
        names = [p["name"] for p in inst["parts"] if p["role"] == role]
        if names:
            lines.append(f"- {what.capitalize()}: {', '.join(names)}.")
    lines.append(f"- Detector `{inst['detector']}` ({inst['detector_shape']}, sensitive area "
                 f"{inst['detector_area_mm2']:.4g} mm^2); it absorbs everything that reaches it.")
    return lines


def _numbers_line(result: StudyResult) -> str:
    """The result files this report folder really holds."""
    names = ("results.json", "pst.csv", "pst.json", "sweep.csv", "paths.csv", "critical.csv")
    have = [n for n in names if (result.out_dir / n).exists()]
    return "- Numbers: " + ", ".join(have) + "."


def _title(result) -> str:
    if result.config.model is not None:
        return f"Stray-light study of {result.config.model}"
    return "Baffle design study" if result.config.scene is None else f"Stray-light study of {result.config.scene}"


def _builtin(result) -> bool:
    return result.config.scene is None and result.config.model is None


def _short_name(setup) -> str:
    return "Baffled tube" if setup.params else str(setup.description).replace("scene ", "Scene ", 1)


def _pst_plot(pst, setup, path, material: str = "") -> bool:
    """PST plot with the unscattered (geometric) transmission drawn for comparison (when the scene gives it;
    returns whether it did), and below it each point's relative 1-sigma error in %: on a log axis spanning many
    decades a 2 % error bar is thinner than its marker, so the panel shows the bars' size."""
    import matplotlib.pyplot as plt

    fig, (ax, ax_err) = plt.subplots(2, 1, figsize=(7.5, 6.0), dpi=120, sharex=True,
                                     gridspec_kw={"height_ratios": [3, 1]})
    pst.plot(ax=ax, label_prefix="Monte Carlo ")
    drawn = False
    a = np.linspace(0.0, max(pst.off_axis_deg), 400)
    direct = benchmark_direct_ratio(np.radians(a), setup.params)
    if np.any(direct > 0) and setup.entrance is not None:
        # entrance ratio -> PST: times entrance area * cos a / detector area
        r_e = setup.entrance.radius_mm
        conv = math.pi * r_e**2 * np.cos(np.radians(a)) / pst.detector_area_mm2
        ok = direct > 0
        ax.plot(a[ok], (direct * conv)[ok], "k--", lw=1, label="unscattered (geometric) transmission")
        drawn = True
    share = unscattered_share(pst)
    computed = np.isfinite(share) & (share > 0)
    if computed.any():  # the straight light the tracer computed (direct_area), in PST units
        ax.plot(pst.off_axis_deg[computed], (pst.pst * share)[computed], "k+", ms=9,
                label="unscattered light (computed exactly)")
        drawn = True
    ax.legend(fontsize=8)
    ax.set_xlabel("")
    pos = pst.pst > 0
    rel = np.where(pos, pst.pst_stderr / np.where(pos, pst.pst, 1.0), np.nan) * 100
    ax_err.plot(pst.off_axis_deg[pos], rel[pos], "o", ms=4)
    ax_err.vlines(pst.off_axis_deg[pos], 0, rel[pos], lw=2)
    ax_err.set_ylim(0, max(1.0, float(np.nanmax(rel)) * 1.2) if np.any(pos) else 1.0)
    ax_err.set_ylabel("1 sigma (%)", fontsize=8)
    ax_err.set_xlabel("off-axis angle (deg)")
    ax_err.grid(True, alpha=0.3)
    prm = setup.params or {}
    what, extra = ((f"the baffled tube: {prm.get('vane_count', '?')} vanes "
                    f"(hole r = {prm.get('vane_inner_radius_mm', float('nan')):g} mm)", f"coating {material}; ")
                   if prm else (setup.description, ""))
    rays = (f"{pst.rays:.2g} rays per angle" if pst.precision is None
            else f"traced to {pst.precision['target_rel_error']:.1%} rel. error (or a cap)")
    ax.set_title(f"Point source transmittance of {what}\n{extra}{rays}; 1-sigma error bars, their size in % "
                 f"below", fontsize=9)
    fig.tight_layout()
    atomicio.write_figure(fig, path)
    plt.close(fig)
    return drawn


def _reliability_word(row) -> str:
    """'yes', or 'NO: ...' naming why the error bar of a PST point cannot be trusted."""
    flags = set(row.get("flags", "").split(";")) - {""}
    why = []
    if "unreliable_error" in flags:
        why.append(f"VOV {row['vov']:.2g} > 0.1")
    if "target_not_reached" in flags:
        why.append(f"stopped by {row.get('stop_reason')} before the target")
    if "zero" in flags:
        why.append("nothing detected")
    return "NO: " + ", ".join(why) if why else "yes"


def _pst_reliability_note(pst) -> str:
    """A warning line when some PST error bars are not reliable ('' when all are)."""
    bad = [f"{r['off_axis_deg']:g}" for r in pst.flagged_rows() if _reliability_word(r) != "yes"]
    if not bad:
        return ""
    held = [f"at {r['off_axis_deg']:g} deg one ray holds {r['heaviest_path']['variance_share']:.0%} of the variance: "
            f"{r['heaviest_path']['family']}" + (f" ({r['heaviest_path']['hint']})" if r["heaviest_path"].get("hint") else "")
            for r in pst.flagged_rows() if _reliability_word(r) != "yes" and r.get("heaviest_path")]
    return (f"**Warning: the error bars at {', '.join(bad)} deg are not reliable** (rare heavy paths: VOV > 0.1, "
            "or a cap stopped the point before its target). Trace those angles longer "
            "(`straylight pst --target-rel-error E --max-seconds S`) before quoting them."
            + ("".join(f" {h[0].upper()}{h[1:]}." for h in held)))


def _html_warning(note: str) -> str:
    """The reliability note as an HTML paragraph (markdown bold and code turned into tags)."""
    if not note:
        return ""
    text = html.escape(note)
    text = re.sub(r"`([^`]*)`", r"<code>\1</code>", re.sub(r"\*\*(.*?)\*\*", r"<strong>\1</strong>", text))
    return f'<p class="warning" style="color:#a00">{text}</p>\n'


def _pst_table_rows(pst, direct):
    rows = []
    for i, (a, row) in enumerate(zip(pst.off_axis_deg, pst.flagged_rows())):
        rel = pst.pst_stderr[i] / pst.pst[i] if pst.pst[i] > 0 else math.nan
        d = direct[i] if i < len(direct) else math.nan
        vov = row.get("vov")
        rows.append((f"{a:g}", f"{pst.pst[i]:.3e}", f"{pst.pst_stderr[i]:.2e}", f"{rel:.1%}" if rel == rel else "-",
                     f"{vov:.2g}" if vov is not None and vov == vov else "-",
                     f"{pst.entrance_ratio[i]:.3e}", f"{d:.3e}" if np.isfinite(d) else "-", f"{row['rays']:.3g}",
                     row.get("stop_reason", "rays given"), f"{pst.seconds[i]:.1f}", _reliability_word(row)))
    return rows


PST_HEADER = ("off-axis (deg)", "PST", "1 sigma", "rel. error", "VOV (error of the error)",
              "detector / entrance power", "unscattered (geometric) detector / entrance power", "rays",
              "stopped by", "time (s)", "error bar reliable?")


def _md_table(header, rows) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def _without_empty_columns(header, rows):
    """(header, rows) without the columns whose every cell is "-" (nothing to say for this instrument)."""
    rows = [tuple(r) for r in rows]
    keep = [k for k in range(len(header)) if not rows or any(str(r[k]) != "-" for r in rows)]
    return tuple(header[k] for k in keep), [tuple(r[k] for k in keep) for r in rows]


def _inline_html(text: str) -> str:
    """A Markdown list line as HTML inside <li>: no leading "- ", `code` as <code>, the rest escaped."""
    text = text[2:] if text.startswith("- ") else text
    parts = text.split("`")
    return "".join(f"<code>{html.escape(p)}</code>" if k % 2 else html.escape(p) for k, p in enumerate(parts))


def _html_table(header, rows) -> str:
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>" for r in rows)
    return f'<div class="table-wrap"><table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table></div>'


def _findings(pst, report, crit, sweep, builtin: bool = True) -> list[str]:
    out = []
    stray = [i for i, a in enumerate(pst.off_axis_deg) if a >= 20]
    if stray:
        i = stray[0]
        out.append(f"PST at {pst.off_axis_deg[i]:g} deg off axis: {pst.pst[i]:.2e} +- {pst.pst_stderr[i]:.1e}"
                   + (" (only scattered light reaches the detector past the geometric cut-off)." if builtin else "."))
    if report.rows:
        top = report.rows[0]
        out.append(f"Largest stray-light path at {crit.off_axis_deg:g} deg: {top.label} "
                   f"({top.fraction:.1%} +- {top.fraction_stderr:.1%} of the detector power).")
        once = report.ancestry_w.get("scattered_once", (0.0, 0.0))[0]
        if report.total_w > 0:
            out.append(f"Single-scatter paths carry {once / report.total_w:.1%} of the detector power.")
    if crit.ranking:
        out.append("Parts both illuminated and seen by the detector (ranked): "
                   + ", ".join(r.part for r in crit.ranking[:5]) + ".")
    for j, a in enumerate(sweep.off_axis_deg if sweep is not None else ()):
        col, err = sweep.pst[:, j], sweep.pst_stderr[:, j]
        k = int(np.nanargmin(col))
        # designs whose PST is within 2 combined sigma of the lowest cannot be told apart
        ties = [f"{v:g}" for i, v in enumerate(sweep.values)
                if i != k and col[i] - col[k] < 2 * math.hypot(err[i], err[k])]
        out.append(f"Design sweep at {a:g} deg: lowest PST with {sweep.parameter.replace('_', ' ')} = "
                   f"{sweep.values[k]:g} ({col[k]:.2e} +- {err[k]:.1e}; with {sweep.values[0]:g}: {col[0]:.2e})"
                   + (f"; within 2 sigma of it: {', '.join(ties)}." if ties else "."))
    return out


def write_markdown(result: StudyResult, pst, report, crit, sweep, direct) -> Path:
    from straylight.analyses.ghost_study import markdown_lines as ghost_markdown

    lines = [f"# {_title(result)}", "", result.summary["description"], "", "## Findings", ""]
    lines += [f"- {f}" for f in _findings(pst, report, crit, sweep, _builtin(result))]
    note = _pst_reliability_note(pst)
    lines += ["", "## Point source transmittance", "", "![PST](pst.png)", "", *([note, ""] if note else []),
              _md_table(*_without_empty_columns(PST_HEADER, _pst_table_rows(pst, direct))), "",
              "## Stray-light paths", "", "![paths](paths.png)", "", report.markdown(15), "",
              "## Critical and illuminated objects", "", "![critical](critical.png)", "", crit.markdown(), "",
              *ghost_markdown(result.summary.get("ghosts")),
              *(["## Design sweep", "", "![sweep](sweep.png)", ""] if sweep is not None else []),
              "## 3-D views and detector map", "", "![rays](view_rays.png)", "", "![absorbed](view_absorbed.png)",
              "", "![map](detector_map.png)", "", "## Method", "", *_method_lines(result)]
    path = result.out_dir / "report.md"
    atomicio.write_text(path, "\n".join(lines) + "\n")
    return path


def _method_lines(result: StudyResult) -> list[str]:
    cfg = result.config
    t = result.timings_s
    return [
        "- PST = detector irradiance / beam irradiance normal to the rays; the entrance ratio is detector "
        "power / beam power crossing the entrance disk (docs/reference/outputs.md).",
        "- Forward Monte Carlo with next-event estimation toward the detector (docs/engine.md); error bars "
        "are 1 standard error of the mean over rays.",
        (f"- PST points traced to a relative standard error of {cfg.precision.target_rel_error:.1%} with a "
         f"reliable error estimate (VOV <= {cfg.precision.max_vov:g}), or a cap of {cfg.precision.max_rays:.3g} rays"
         + (f" / {cfg.precision.max_seconds:g} s" if math.isfinite(cfg.precision.max_seconds) else "")
         + " per point; the table says which stopped each point (docs/study.md)." if cfg.precision else
         "- VOV: the estimated relative variance of each point's variance (MCNP's check, < 0.1 means the "
         "error bar can be trusted to ~16 %; larger: rare heavy paths; docs/study.md)."),
        f"- Rays: {cfg.rays if cfg.precision is None else 'see the table'} per PST angle, "
        + (f"{cfg.sweep_rays} per design-sweep point, " if result.summary.get("sweep") is not None else "")
        + f"{cfg.path_rays} for the "
        f"path report, {cfg.critical_rays} each way for critical/illuminated objects. Seed {cfg.seed} "
        "(each step and point derives its own stream from it).",
        *_instrument_lines(result),
        "- Wall time (s): " + ", ".join(f"{k} {v:.1f}" for k, v in t.items()) + ".",
        _numbers_line(result),
    ]


def write_html(result: StudyResult, pst, report, crit, sweep, direct) -> Path:
    """index.html: findings, plots and tables, readable without a server."""
    def img(name, alt, width="100%"):
        return f'<figure><img src="{name}" alt="{html.escape(alt)}" style="max-width:{width}"><figcaption>' \
               f"{html.escape(alt)}</figcaption></figure>"

    def csv(name):  # link to the table's CSV (straylight.analyses.tables), when written
        f = f"table_{name}.csv"
        return f'<p style="font-size:0.85em"><a href="{f}">{f}</a></p>' if (result.out_dir / f).exists() else ""

    path_rows = [(r.rank, r.label, r.ancestry.replace("_", " "), f"{r.fraction:.2%}", f"{r.fraction_stderr:.2%}",
                  f"{r.power_w:.2e}", r.n_records) for r in report.rows[:15]]
    anc_rows = [(k.replace("_", " "), f"{v[0] / report.total_w:.2%}" if report.total_w > 0 else "-",
                 f"{v[1] / report.total_w:.2%}" if report.total_w > 0 else "-") for k, v in report.ancestry_w.items()]
    ranked = crit.ranking + [r for r in sorted(crit.rows, key=lambda r: -(r.illuminated + r.view_factor))
                             if r not in crit.ranking]
    crit_rows = [(i + 1 if r in crit.ranking else "-", r.part, f"{r.illuminated:.3e} +- {r.illuminated_stderr:.1e}",
                  f"{r.view_factor:.3e} +- {r.view_factor_stderr:.1e}", f"{r.score:.2e}") for i, r in enumerate(ranked)]
    sweep_html = ""
    if sweep is not None:
        sweep_rows = [(f"{v:g}", *[f"{sweep.pst[i, j]:.2e} +- {sweep.pst_stderr[i, j]:.1e}"
                                   for j in range(len(sweep.off_axis_deg))]) for i, v in enumerate(sweep.values)]
        sweep_html = f"""<h2>Design sweep: {html.escape(sweep.parameter.replace('_', ' '))}</h2>
{img('sweep.png', 'PST vs design parameter at the stray-light angles')}
{_html_table((sweep.parameter,) + tuple(f'PST at {a:g} deg' for a in sweep.off_axis_deg), sweep_rows)}{csv('sweep')}"""
    from straylight.analyses.ghost_study import report_section as ghost_section
    from straylight.thermal.report import report_section as thermal_section
    from straylight.view3d import report_section

    view3d_html = report_section() if (result.out_dir / "view3d.html").exists() else ""
    body = f"""
<h1>{html.escape(_title(result))}</h1>
<p>{html.escape(result.summary['description'])}</p>
<h2>Findings</h2>
<ul>{''.join(f'<li>{html.escape(f)}</li>' for f in _findings(pst, report, crit, sweep, _builtin(result)))}</ul>
<h2>Point source transmittance</h2>
{img('pst.png', 'PST vs off-axis angle, 1-sigma error bars (their size in % in the lower panel)'
    + (', with the unscattered (geometric) transmission'
       if any(x for x in result.summary.get('geometric_direct_entrance_ratio') or [] if x) else ''))}
{_html_warning(_pst_reliability_note(pst))}{_html_table(*_without_empty_columns(PST_HEADER, _pst_table_rows(pst, direct)))}{csv('pst')}
<p>Entrance-normalised ratio: <a href="entrance_ratio.png">entrance_ratio.png</a>; numbers in
<a href="pst.csv">pst.csv</a>.</p>
<h2>Stray-light paths at {crit.off_axis_deg:g} deg</h2>
{img('paths.png', 'Largest paths to the detector, fraction of detector power')}
<p>Detector total {report.total_w:.3e} +- {report.total_stderr_w:.1e} W for a 1 W beam.</p>
{_html_table(('rank', 'path', 'ancestry', 'fraction', '1 sigma', 'power (W)', 'records'), path_rows)}{csv('paths')}
{_html_table(('ancestry', 'fraction', '1 sigma'), anc_rows)}{csv('ancestry')}
<h2>Critical and illuminated objects at {crit.off_axis_deg:g} deg</h2>
{img('critical.png', 'View factor from the detector vs fraction of the beam first hitting each part', '70%')}
{_html_table(('rank', 'part', 'illuminated fraction', 'view factor det -> part', 'score'), crit_rows)}{csv('critical')}
{ghost_section(result.summary.get("ghosts"))}
{sweep_html}
{thermal_section(result.out_dir)}{csv('thermal')}
{view3d_html}
<h2>3-D views and detector map</h2>
{img('view_rays.png', 'Cut-away view with traced rays (colour: log10 relative power; red: reaching the detector)')}
{img('view_absorbed.png', 'Cut-away view coloured by absorbed power per part')}
{img('detector_map.png', 'Detector irradiance map', '60%')}
<h2>Method</h2>
<ul>{''.join(f'<li>{_inline_html(x)}</li>' for x in _method_lines(result))}</ul>
"""
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(_title(result))}</title>
<style>
body {{ font-family: sans-serif; max-width: 1000px; margin: 2em auto; padding: 0 1em; color: #222; }}
table {{ border-collapse: collapse; margin: 0.8em 0; font-size: 0.9em; }}
th, td {{ border: 1px solid #ccc; padding: 0.25em 0.6em; text-align: right; }}
td {{ white-space: nowrap; }}  /* numbers such as 1.2e-05 never break at their minus sign */
td:nth-child(2) {{ text-align: left; white-space: normal; }}
.table-wrap {{ overflow-x: auto; }}
figure {{ margin: 1em 0; }} figcaption {{ font-size: 0.85em; color: #555; }}
</style></head><body>{body}</body></html>
"""
    path = result.out_dir / "index.html"
    atomicio.write_text(path, page)
    return path
