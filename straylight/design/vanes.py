"""``straylight design vanes`` end to end: construct, refine, evaluate, write DIR (CONTRACTS 4.6).

1. :func:`straylight.design.construction.construct` places the vanes (exact geometry).
2. :func:`straylight.design.refine.refine` moves them along z to lower the PST over the band
   E, E + 5, E + 10 deg (common random numbers, seed derived from ``seed``; skipped with
   ``refine_evals=0``).
3. The construction and the refined layout are traced again with ``rays`` per angle and the
   user's ``seed`` (fresh streams: the optimiser's lucky draws do not carry over). The evenly
   spaced baseline (same count, same envelope) and the bare tube (no vanes) are traced with the
   same seed, angles and rays. The design (``design_source``) is the lowest band objective among
   the baseline and the construction or refined layouts that trace no worse than it at any band
   angle (:func:`choose_design`): the tool never returns a layout worse than the plain one.
4. DIR/design.json, DIR/scene.toml (+ one PLY per part), DIR/design.step, DIR/index.html.
"""
from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from atomicio import write_json
from straylight.checkpoints import PointStore
from straylight.design import model
from straylight.design.construction import BaffleSpec, construct, evenly_spaced, layout_at
from straylight.design.evaluate import log_objective, pst_points
from straylight.design.refine import refine
from straylight.design.report import write_report
from straylight.execution import Execution, as_execution

PST_DEFINITION = "(detector power / detector area) / beam irradiance normal to the rays (docs/reference/outputs.md)"


def band_angles(spec: BaffleSpec) -> list[float]:
    """E, E + 5, E + 10 deg (those below 89 deg; at least E)."""
    return [a for a in (spec.exclusion_deg + d for d in (0.0, 5.0, 10.0)) if a < 89.0] or [spec.exclusion_deg]


def optimiser_seed(seed: int) -> int:
    """The optimiser's own stream, independent of the final evaluation's ``seed``."""
    return int(np.random.SeedSequence([int(seed), 16]).generate_state(1)[0])


def design_vanes(spec: BaffleSpec, out, *, material="z302_sample_b", rays: int = 100_000, seed: int = 0,
                 refine_rays: int | None = None, refine_evals: int = 40, execution: Execution | None = None,
                 log=print, resume: bool = False) -> dict:
    """Design the vanes of ``spec``'s tube and write DIR (see the module docstring); returns design.json's dict.

    ``execution``: where the layouts are traced (threads, dask...; never a different number) and
    whether the optimiser shows progress (:class:`straylight.execution.Execution`).

    The final PST evaluations are kept point by point in DIR/design.points until design.json is
    written; ``resume`` reads back those an interrupted run finished (the optimiser is re-run: it is
    seeded, so it ends at the same layout)."""
    with as_execution(execution).opened() as ex:  # one cluster (or none) for every layout traced
        return _design_vanes(spec, Path(out), material, rays, seed, refine_rays, refine_evals, ex, log, resume)


def _design_vanes(spec, out: Path, material, rays, seed, refine_rays, refine_evals, execution: Execution, log,
                  resume) -> dict:
    if isinstance(rays, bool) or int(rays) < 1:
        raise ValueError(f"rays must be a positive integer, got {rays!r}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    _, _, models = model.coating(material)
    built = construct(spec)
    log(f"construction: {len(built.vanes)} vanes at z = "
        + ", ".join(f"{v.z_mm:.1f}" for v in built.vanes) + " mm"
        + ("" if built.complete else f" (incomplete: {'; '.join(built.notes)})"))
    angles = band_angles(spec)
    # checked before the optimiser runs: a resume with other settings is refused at once
    store = PointStore(out / "design.points", {
        "spec": built.to_dict()["spec"], "material": material, "angles": angles, "rays": int(rays),
        "seed": int(seed)}, resume=resume)
    refine_rays = int(refine_rays or max(2_000, int(rays) // 5))
    refinement = None
    if refine_evals > 0 and built.vanes:
        refinement = refine(spec, [v.z_mm for v in built.vanes], models, angles, rays=refine_rays,
                            seed=optimiser_seed(seed), max_evals=int(refine_evals), execution=execution,
                            also_z_mm=[v.z_mm for v in evenly_spaced(spec, len(built.vanes)).vanes])
        log(f"refinement: {refinement.stop_reason}; J {refinement.start_objective:.3f} -> "
            f"{refinement.best_objective:.3f} (+- {refinement.start_objective_stderr:.3f})")

    slots = iter(range(4))

    def traced(layout):
        return pst_points(spec, layout.vanes, models, angles, int(rays), int(seed), execution=execution, store=store,
                          slot=next(slots))

    built_pst = traced(built)
    candidates = [(built, built_pst, "construction")]
    if refinement is not None and refinement.best_z_mm != refinement.start_z_mm:
        refined = layout_at(spec, refinement.best_z_mm)
        candidates.append((refined, traced(refined), "refined"))
    baseline = evenly_spaced(spec, len(built.vanes))
    baseline_pst = traced(baseline)
    if built.vanes:
        design, design_pst, source = choose_design(candidates, (baseline, baseline_pst, "evenly spaced"))
    else:
        design, design_pst, source = candidates[0]
    bare = layout_at(spec, [])
    bare_pst = traced(bare)

    model.write_scene(spec, design.vanes, material, out)
    model.write_step(spec, design.vanes, out / "design.step")
    doc = {
        "command": "straylight design vanes",
        "inputs": {**built.to_dict()["spec"], "material": str(material) if isinstance(material, (str, Path))
                   else getattr(material, "name", "model"), "rays": int(rays), "seed": int(seed)},
        "frame": "tube axis z; wall r = R, 0 <= z <= L; entrance z = L; detector r <= S at z = 0 facing +z",
        "vanes": [v.to_dict() for v in design.vanes],
        "pst": [p.to_dict() for p in design_pst],
        "pst_definition": PST_DEFINITION,
        "design_source": source,
        "geometry": _geometry(design),
        "baseline": {"description": "same count evenly spaced, z_k = k L / (N + 1), inner edges on the same "
                                    "field envelope; same angles, rays and seed",
                     "vanes": [v.to_dict() for v in baseline.vanes], "pst": [p.to_dict() for p in baseline_pst],
                     "geometry": _geometry(baseline)},
        "no_vanes": {"pst": [p.to_dict() for p in bare_pst]},
        "construction": {"vanes": [v.to_dict() for v in built.vanes], "pst": [p.to_dict() for p in built_pst],
                         "geometry": _geometry(built), "notes": list(built.notes)},
        "ratio_to_baseline": [_ratio(d, b) for d, b in zip(design_pst, baseline_pst)],
        "optimiser": refinement.to_dict() if refinement is not None else None,
        "files": {"scene": "scene.toml", "step": "design.step", "report": "index.html"},
        "seconds": None,
    }
    doc["seconds"] = round(time.perf_counter() - t_start, 1)
    write_report(out, spec, doc, built, design, baseline, refinement)
    write_json(out / "design.json", doc)
    store.remove()
    return doc


def not_worse(points, base_points, sigmas: float = 2.0) -> bool:
    """No angle where ``points`` trace significantly above ``base_points`` (by more than ``sigmas``
    combined standard errors)."""
    return all(p.pst <= b.pst + sigmas * math.hypot(p.pst_stderr, b.pst_stderr) for p, b in zip(points, base_points))


def choose_design(candidates, baseline):
    """The design among (layout, pst points, name) ``candidates`` and the evenly spaced
    ``baseline``: the lowest band objective (:func:`straylight.design.evaluate.log_objective`) among
    the baseline and the candidates that are :func:`not_worse` than it at any angle of the band
    (CONTRACTS 4.6: light at E *and beyond* rejected as well as the vanes allow; a layout that
    trades E + 10 for E is not returned over the plain one). The baseline shares the field
    envelope, so the field stays clear whichever is chosen."""
    fair = [c for c in candidates if not_worse(c[1], baseline[1])] + [baseline]
    return min(fair, key=lambda c: log_objective(c[1])[0])


def _geometry(layout) -> dict:
    d = layout.to_dict()
    return {"complete": d["complete"], "lit_and_seen_mm": d["lit_and_seen_mm"],
            "vignetting_margin_mm": d["vignetting_margin_mm"], "bays": d["bays"]}


def _ratio(design_point, base_point) -> dict:
    """Design / baseline PST with its 1-sigma error (independent-error propagation: conservative,
    the two share random numbers, which only makes the true error of the ratio smaller)."""
    d, b = design_point, base_point
    if d.pst <= 0 or b.pst <= 0:
        return {"off_axis_deg": d.off_axis_deg, "ratio": None, "ratio_stderr": None}
    r = d.pst / b.pst
    return {"off_axis_deg": d.off_axis_deg, "ratio": r,
            "ratio_stderr": r * math.hypot(d.pst_stderr / d.pst, b.pst_stderr / b.pst)}
