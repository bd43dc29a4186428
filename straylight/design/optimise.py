"""Vane optimiser at a fixed vane count: positions, bevel angle and bevel side, from the Freniere start.

- Variables: the vanes' centres z_k (each inner edge kept on the field envelope S + z tan F, the
  smallest hole that does not vignette the field: a larger hole only uncovers more wall, a smaller
  one vignettes), the bevel angle and the bevel side of the vanes' edges. The count never changes.
- Objective: J = mean over the band (E, E + 5, E + 10 deg) of ln PST
  (:func:`straylight.design.evaluate.log_objective`) traced with common random numbers (one seed
  for every candidate), so J is a deterministic function of the design.
- Method: for each bevel candidate (angle, side) the Freniere positions are traced; the best few
  are then refined in z by :func:`straylight.design.refine.refine` (bounded Nelder-Mead on the same
  CRN objective). The start (the Freniere construction with the spec's own bevel) is always one of
  the candidates, so the result is never worse than the start on the CRN objective.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

from straylight.design.construction import BaffleSpec, construct
from straylight.design.evaluate import log_objective, pst_points
from straylight.design.refine import feasible, refine
from straylight.execution import Execution, as_execution

BEVELS = ((0.0, "back"), (30.0, "back"), (45.0, "back"), (60.0, "back"), (45.0, "front"))


@dataclass
class Optimised:
    """Result of :func:`optimise_vanes`."""

    spec: BaffleSpec
    z_mm: list
    start_objective: float
    start_objective_stderr: float
    best_objective: float
    tried: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"method": "bevel (angle, side) candidates at the Freniere positions, then bounded Nelder-Mead "
                          "in z, common random numbers",
                "objective": "mean over the band E, E+5, E+10 deg of ln(PST)",
                "bevel_deg": self.spec.bevel_deg, "bevel_side": self.spec.bevel_side, "z_mm": self.z_mm,
                "start_objective": self.start_objective, "start_objective_stderr": self.start_objective_stderr,
                "best_objective": self.best_objective, "tried": self.tried}


def _fits(spec, z_mm) -> bool:
    if feasible(spec, z_mm):
        return False
    run = spec.bevel_run_mm
    return all(spec.vane_at(z).inner_radius_mm + run < spec.tube_radius_mm for z in z_mm)


def optimise_vanes(spec, material_models: dict, angles_deg, *, rays: int, seed: int, max_evals: int = 30,
                   bevels=BEVELS, refine_best: int = 1, execution: Execution | None = None) -> Optimised:
    """Minimise J over vane positions and bevel at the Freniere construction's count; see the module docstring.

    ``max_evals``: traced layouts for each z refinement (0: bevel candidates only)."""
    ex = as_execution(execution)
    start_z = [v.z_mm for v in construct(spec).vanes]

    def j_of(s, z):
        pts = pst_points(s, [s.vane_at(x) for x in z], material_models, angles_deg, rays, seed, execution=ex)
        return log_objective(pts)

    j0, se0 = j_of(spec, start_z)
    best = (j0, spec, list(start_z))
    tried = [{"bevel_deg": spec.bevel_deg, "bevel_side": spec.bevel_side, "z_mm": list(start_z), "objective": j0,
              "stage": "start (Freniere)"}]
    if not start_z or not math.isfinite(j0):
        return Optimised(spec, list(start_z), j0, se0, j0, tried)
    scored = [(j0, spec)]
    for deg, side in bevels:
        s = dataclasses.replace(spec, bevel_deg=float(deg), bevel_side=side)
        if (s.bevel_deg, s.bevel_side) == (spec.bevel_deg, spec.bevel_side) or not _fits(s, start_z):
            continue
        j, _ = j_of(s, start_z)
        tried.append({"bevel_deg": s.bevel_deg, "bevel_side": side, "z_mm": list(start_z), "objective": j,
                      "stage": "bevel at Freniere positions"})
        scored.append((j, s))
        if j < best[0]:
            best = (j, s, list(start_z))
    if max_evals > 0:
        for _, s in sorted(scored, key=lambda t: t[0])[:max(1, int(refine_best))]:
            r = refine(s, start_z, material_models, angles_deg, rays=rays, seed=seed, max_evals=max_evals,
                       execution=ex)
            ok = _fits(s, r.best_z_mm)
            tried.append({"bevel_deg": s.bevel_deg, "bevel_side": s.bevel_side, "z_mm": r.best_z_mm,
                          "objective": r.best_objective if ok else None, "stage": f"z refinement: {r.stop_reason}"})
            if ok and r.best_objective < best[0]:
                best = (r.best_objective, s, list(r.best_z_mm))
    return Optimised(best[1], best[2], j0, se0, best[0], tried)
