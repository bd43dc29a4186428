"""PST of a vane layout, defined and seeded exactly as ``straylight pst`` (CONTRACTS 4.5).

PST = (detector power / detector area) / beam irradiance normal to the rays, the beam being the
scene file's collimated disk (:func:`straylight.design.model.beam`) tilted toward +x; angle i of
a list is traced with seed ``point_seed(seed, i)`` and next-event estimation with first- and second-vertex
sampling, as :func:`straylight.analyses.pst.pst_sweep` does. So the same seed and angle list give
the same numbers as ``straylight pst DIR/scene.toml``, and two layouts evaluated with the same
seed share their random numbers (common random numbers: their difference is not dominated by
noise, since the source rays and most of the early random choices are the same).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from straylight.analyses.estimators import estimator_options
from straylight.analyses.grid import GridPoint, point_seed, run_grid
from straylight.analyses.pst import part_area_mm2, pst_job
from straylight.analyses.types import Setup
from straylight.design import model
from straylight.execution import Execution, as_execution


@dataclass(frozen=True)
class PstPoint:
    """One PST value with its 1-sigma Monte Carlo standard error."""

    off_axis_deg: float
    pst: float
    pst_stderr: float
    rays: int

    def to_dict(self) -> dict:
        return {"off_axis_deg": self.off_axis_deg, "pst": self.pst, "pst_stderr": self.pst_stderr,
                "rays": self.rays}


def pst_points(spec, vanes, material_models: dict, angles_deg, rays: int, seed: int,
               execution: Execution | None = None, store=None, slot: int = 0) -> list[PstPoint]:
    """PST of the tube with ``vanes`` at each off-axis angle (same definition and seeds as ``straylight pst``).

    The angles run on the grid runner (:func:`straylight.analyses.grid.run_grid`, quietly: the
    optimiser shows its own progress). ``store``: a :class:`straylight.checkpoints.PointStore`; angle i
    is kept there as point ``slot * 1000 + i``, tagged with the layout's vane heights, and read back if
    an earlier run finished it for the same layout."""
    sc = model.scene(spec, vanes)
    bm = model.beam(spec)
    area = part_area_mm2(sc, "detector")
    setup = Setup(sc, material_models, bm, None, "detector")
    opts = estimator_options("default", materials=material_models)  # what `straylight pst` traces: same seed, same numbers
    z_mm = [float(v.z_mm) for v in vanes]
    off_axis = {slot * 1000 + i: math.radians(float(a)) for i, a in enumerate(angles_deg)}
    points = [GridPoint(slot * 1000 + i, point_seed(seed, i), f"{float(a):g} deg", tag=z_mm)
              for i, a in enumerate(angles_deg)]
    runs = run_grid(points, lambda p: pst_job(setup, "detector", area, off_axis[p.key], 0.0, opts),
                    as_execution(execution).quiet(), rays=int(rays), checkpoint=store, desc="PST of a layout")
    return [PstPoint(float(a), r.values["pst"], r.values["pst_stderr"], int(r.rays)) for a, r in zip(angles_deg, runs)]


def log_objective(points) -> tuple[float, float]:
    """(J, stderr of J): J = mean over the band of ln PST (a geometric mean: every angle counts, not
    only the brightest); stderr by the delta method, sqrt(sum (se_i / PST_i)^2) / n."""
    pst = np.array([p.pst for p in points])
    se = np.array([p.pst_stderr for p in points])
    if np.any(pst <= 0):
        return -math.inf, math.inf  # nothing reached the detector: no estimate of the log
    return float(np.mean(np.log(pst))), float(np.sqrt(np.sum((se / pst) ** 2)) / len(pst))
