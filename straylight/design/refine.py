"""Monte Carlo refinement of a vane layout: move the vanes along z to lower the PST beyond E.

- Variables: the vanes' centres z_k. Each inner edge stays on the field envelope (so nothing in
  the field vignettes, whatever the move); the count stays.
- Objective: J = mean over the band (E, E + 5, E + 10 deg) of ln PST
  (:func:`straylight.design.evaluate.log_objective`), traced with common random numbers: every
  candidate uses the same seed, so the same source rays and random streams, and J(x) is a
  deterministic function of the layout that a derivative-free optimiser can follow.
- Optimiser: scipy's Nelder-Mead (bounded), started from the construction with a simplex of
  upward steps of an eighth of the local vane pitch, one vertex replaced by the evenly spaced
  layout. Infeasible layouts (overlapping vanes, outside the
  tube, in a keep-out zone) are rejected without tracing.
- Stopping rule: the simplex's objective values lie within ``fatol`` = the standard error of J
  at the start (differences smaller than one evaluation's error are not resolved) and its
  vertices within ``xatol_mm``; or the evaluation budget is spent.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from straylight.design.construction import GAP_MM
from straylight.design.evaluate import log_objective, pst_points
from straylight.execution import Execution, as_execution
from straylight.progress import progress_bar

INFEASIBLE = "infeasible"


@dataclass
class Evaluation:
    """One objective evaluation of the optimiser."""

    index: int
    z_mm: list
    objective: float | None
    objective_stderr: float | None
    pst: list
    seconds: float
    status: str = "ok"

    def to_dict(self) -> dict:
        return {"index": self.index, "z_mm": self.z_mm, "objective": self.objective,
                "objective_stderr": self.objective_stderr, "pst": self.pst, "seconds": self.seconds,
                "status": self.status}


@dataclass
class Refinement:
    """Result of :func:`refine`: the best layout found and the optimiser's history."""

    start_z_mm: list
    best_z_mm: list
    start_objective: float
    start_objective_stderr: float
    best_objective: float
    evaluations: list = field(default_factory=list)
    stop_reason: str = ""
    fatol: float = math.nan
    xatol_mm: float = math.nan
    angles_deg: tuple = ()
    rays: int = 0
    seed: int = 0

    def to_dict(self) -> dict:
        return {"method": "Nelder-Mead (scipy.optimize.minimize, bounded), common random numbers",
                "objective": "mean over angles_deg of ln(PST)", "angles_deg": list(self.angles_deg),
                "rays_per_angle": self.rays, "seed": self.seed, "start_z_mm": self.start_z_mm,
                "best_z_mm": self.best_z_mm, "start_objective": self.start_objective,
                "start_objective_stderr": self.start_objective_stderr, "best_objective": self.best_objective,
                "fatol": self.fatol, "xatol_mm": self.xatol_mm, "stop_reason": self.stop_reason,
                "evaluations": [e.to_dict() for e in self.evaluations]}


class _Budget(Exception):
    pass


def feasible(spec, z_mm) -> str | None:
    """None if vanes centred at ``z_mm`` fit (inside the tube, apart, out of keep-out zones), else why."""
    z = np.sort(np.asarray(z_mm, dtype=float))
    half = spec.vane_thickness_mm / 2
    if len(z) and (z[0] - half <= GAP_MM or z[-1] + half >= spec.tube_length_mm - GAP_MM):
        return "outside the tube"
    if len(z) > 1 and np.min(np.diff(z)) <= spec.vane_thickness_mm + GAP_MM:
        return "vanes overlap"
    for lo, hi in spec.keep_out_mm:
        if np.any((z + half > lo) & (z - half < hi)):
            return "in a keep-out zone"
    return None


def refine(spec, start_z_mm, material_models: dict, angles_deg, *, rays: int, seed: int, max_evals: int = 40,
           xatol_mm: float = 0.5, execution: Execution | None = None, also_z_mm=None) -> Refinement:
    """Minimise J over the vane positions from ``start_z_mm``; see the module docstring.

    execution : where the layouts are traced (:class:`straylight.execution.Execution`); its ``progress``
        shows the optimiser's bar

    also_z_mm : another layout of the same count (the evenly spaced one) made a vertex of the
        initial simplex, so the search spans both.
    """
    from scipy.optimize import minimize

    ex = as_execution(execution)
    x0 = np.sort(np.asarray(start_z_mm, dtype=float))
    n = len(x0)
    history: list[Evaluation] = []

    def evaluate(x):
        t0 = time.perf_counter()
        vanes = [spec.vane_at(z) for z in np.sort(x)]
        pts = pst_points(spec, vanes, material_models, angles_deg, rays, seed, execution=ex)
        j, se = log_objective(pts)
        return j, se, pts, time.perf_counter() - t0

    j0, se0, pts0, sec0 = evaluate(x0)
    history.append(Evaluation(0, x0.tolist(), j0, se0, [p.to_dict() for p in pts0], sec0))
    result = Refinement(x0.tolist(), x0.tolist(), j0, se0, j0, history, "", float(se0), float(xatol_mm),
                        tuple(float(a) for a in angles_deg), int(rays), int(seed))
    if n == 0 or not math.isfinite(j0):
        result.stop_reason = "nothing to refine (no vanes, or no light on the detector)"
        return result
    bar = progress_bar(total=max_evals, desc="refining vanes", unit="layout", enabled=ex.progress)
    bar.update(1)
    best = {"j": j0, "x": x0.copy()}
    penalty = j0 + 10.0

    seen = {tuple(np.round(x0, 9)): j0}

    def objective(x):
        key = tuple(np.round(np.sort(x), 9))
        if key in seen:  # Nelder-Mead re-asks for points it has (the start, shrunk vertices)
            return seen[key]
        why = feasible(spec, x)
        if why:
            history.append(Evaluation(len(history), np.sort(x).tolist(), None, None, [], 0.0, f"{INFEASIBLE}: {why}"))
            return penalty
        if sum(e.status == "ok" for e in history) >= max_evals:
            raise _Budget
        j, se, pts, sec = evaluate(x)
        history.append(Evaluation(len(history), np.sort(x).tolist(), j, se, [p.to_dict() for p in pts], sec))
        seen[key] = j
        bar.update(1)
        if j < best["j"]:
            best.update(j=j, x=np.sort(x).copy())
        bar.set_postfix_str(f"J {j:.3f} best {best['j']:.3f} (start {j0:.3f} +- {se0:.3f})")
        return j

    # initial simplex: each vane moved up (toward the entrance: a higher vane hides more of the bay
    # above it, so the construction's guarantee holds) by an eighth of its distance to the nearer
    # neighbour or end; the other layout, if given, replaces the vertex of its largest difference
    edges = np.concatenate([[0.0], x0, [spec.tube_length_mm]])
    steps = 0.125 * np.minimum(np.diff(edges)[:-1], np.diff(edges)[1:])
    simplex = np.vstack([x0] + [x0 + steps[i] * np.eye(n)[i] for i in range(n)])
    if also_z_mm is not None and len(also_z_mm) == n:
        other = np.sort(np.asarray(also_z_mm, dtype=float))
        k = int(np.argmax(np.abs(other - x0)))
        if abs(other[k] - x0[k]) > xatol_mm and feasible(spec, other) is None:
            simplex[k + 1] = other
    half = spec.vane_thickness_mm / 2
    bounds = [(half + 2 * GAP_MM, spec.tube_length_mm - half - 2 * GAP_MM)] * n
    try:
        res = minimize(objective, x0, method="Nelder-Mead", bounds=bounds,
                       options={"initial_simplex": simplex, "xatol": xatol_mm, "fatol": max(se0, 1e-12),
                                "maxfev": 100 * max_evals, "adaptive": n > 3})
        result.stop_reason = (f"converged: simplex values within {se0:.3g} (1 sigma of J) and vertices within "
                              f"{xatol_mm:g} mm" if res.success else f"scipy: {res.message}")
    except _Budget:
        result.stop_reason = f"evaluation budget ({max_evals} layouts) spent"
    finally:
        bar.close()
    result.best_z_mm = best["x"].tolist()
    result.best_objective = float(best["j"])
    return result
