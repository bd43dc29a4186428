"""Design sweep: PST at a few off-axis angles while one tube parameter varies.

Each design value rebuilds the CadQuery tube (``geometry.parts.tube.TubeParams``) and
traces the beam at every angle; each (design, angle) point has its own seed derived from
the user's seed, so points are independent and the sweep is reproducible.
"""
from __future__ import annotations

import math

import numpy as np

from geometry.parts.tube import TubeParams
from straylight.analyses.builtin import tube_setup
from straylight.analyses.grid import GridPoint, open_checkpoint, point_seed, run_grid
from straylight.analyses.pst import detector_area, pst_job
from straylight.analyses.types import SweepResult
from straylight.execution import Execution
from straylight.trace import EstimatorOptions, TraceOptions


def design_sweep(parameter: str = "vane_count", values=range(10), off_axis=(math.radians(20), math.radians(30)),
                 n_rays: int = 50_000, seed: int = 0, material="z302_sample_b", base_params: dict | None = None,
                 nee: bool = True, execution: Execution | None = None, precision=None, checkpoint_dir=None,
                 resume: bool = False) -> SweepResult:
    """PST of the built-in tube at ``off_axis`` (radians) for each value of one ``TubeParams`` field.

    The (design, angle) points run on the grid runner (:func:`straylight.analyses.grid.run_grid`):
    point k = i * n_angles + j has the seed ``point_seed(seed, k)``; a design is built only when one of
    its points is still to trace. ``execution``: where to run and whether to show progress.
    ``precision``: trace each point to a target relative error instead of ``n_rays``.
    ``checkpoint_dir``: each finished point is written there (:class:`straylight.checkpoints.PointStore`);
    ``resume`` reads back the points an interrupted run of the same sweep finished (same numbers)."""
    if parameter not in TubeParams.names():
        raise ValueError(f"unknown design parameter {parameter!r}; one of {', '.join(TubeParams.names())}")
    values = np.asarray(list(values), dtype=np.float64)
    if len(values) == 0:
        raise ValueError("the sweep needs at least one value")
    off_axis = np.atleast_1d(np.asarray(off_axis, dtype=np.float64))
    opts = TraceOptions(estimator=EstimatorOptions(nee=nee, first_vertex_sampling=bool(nee),
                                                   second_vertex_sampling=bool(nee), vertex_lobe_sampling=bool(nee)))
    label = material if isinstance(material, str) else repr(material)
    store = open_checkpoint(checkpoint_dir, {
        "sweep": "design_sweep", "parameter": parameter, "values": values, "off_axis": off_axis,
        "rays": int(n_rays), "seed": int(seed), "material": material, "base_params": base_params, "nee": bool(nee),
        "precision": precision}, resume)
    built: dict = {}

    def setup_of(i: int):
        if i not in built:  # built only when one of its points is still to trace
            params = dict(base_params or {})
            params[parameter] = int(values[i]) if parameter == "vane_count" else float(values[i])
            setup = tube_setup(material=material, **params)
            built[i] = (setup, detector_area(setup, setup.detector).area_mm2)
        return built[i]

    def job(point: GridPoint):
        i, j = divmod(point.key, len(off_axis))
        setup, area = setup_of(i)
        return pst_job(setup, setup.detector, area, off_axis[j], 0.0, opts)

    runs = run_grid(grid_points(values, off_axis, seed, parameter), job, execution, rays=int(n_rays),
                    precision=precision, checkpoint=store, desc=f"sweep {parameter}")
    return sweep_result(parameter, values, off_axis, runs, int(n_rays), int(seed), label)


def grid_points(values, off_axis, seed: int, parameter: str, seed_of=point_seed) -> list[GridPoint]:
    """The (design value, angle) points of a design sweep, k = i * n_angles + j, seed ``seed_of(seed, k)``."""
    n = len(off_axis)
    return [GridPoint(i * n + j, seed_of(seed, i * n + j), f"{parameter}={v:g}, {math.degrees(a):g} deg")
            for i, v in enumerate(values) for j, a in enumerate(off_axis)]


def sweep_result(parameter, values, off_axis, runs, rays: int, seed: int, material: str) -> SweepResult:
    """The (n_values, n_angles) arrays of a design sweep from its grid's :class:`PointRun` list."""
    shape = (len(values), len(off_axis))

    def grid(key):
        return np.array([r.values[key] for r in runs], dtype=np.float64).reshape(shape)

    return SweepResult(parameter, values, np.round(np.degrees(off_axis), 9), grid("pst"), grid("pst_stderr"),
                       grid("entrance_ratio"), grid("entrance_ratio_stderr"),
                       np.array([r.seconds for r in runs]).reshape(shape), rays, seed, material)
