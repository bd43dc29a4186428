"""Design sweep: PST at a few off-axis angles while one tube parameter varies.

Each design value rebuilds the CadQuery tube (``geometry.parts.tube.TubeParams``) and
traces the beam at every angle; each (design, angle) point has its own seed derived from
the user's seed, so points are independent and the sweep is reproducible.
"""
from __future__ import annotations

import math
import time
from contextlib import nullcontext

import numpy as np

from straylight.analyses.pst import dask_client, point_seed
from straylight.analyses.types import SweepResult
from straylight.checkpoints import restore_grid_point, save_grid_point
from straylight.progress import progress_bar

def design_sweep(parameter: str = "vane_count", values=range(10), off_axis=(math.radians(20), math.radians(30)),
                 n_rays: int = 50_000, seed: int = 0, material="z302_sample_b", base_params: dict | None = None,
                 nee: bool = True, workers: int | None = None, scheduler: str | None = None, client=None,
                 progress: bool = True, checkpoint_dir=None, resume: bool = False) -> SweepResult:
    """PST of the built-in tube at ``off_axis`` (radians) for each value of one ``TubeParams`` field.

    ``checkpoint_dir``: each finished (design, angle) point is written there
    (:class:`straylight.checkpoints.PointStore`); ``resume`` reads back the points an interrupted
    run of the same sweep finished (same numbers: every point has its own seed). ``client``: a dask
    client to run on (else one of ``workers``/``scheduler`` for the sweep, or this process)."""

    from geometry.parts.tube import TubeParams
    from straylight.analyses.builtin import tube_setup
    from straylight.trace import TraceOptions, trace

    if parameter not in TubeParams.names():
        raise ValueError(f"unknown design parameter {parameter!r}; one of {', '.join(TubeParams.names())}")
    values = np.asarray(list(values), dtype=np.float64)
    if len(values) == 0:
        raise ValueError("the sweep needs at least one value")
    off_axis = np.atleast_1d(np.asarray(off_axis, dtype=np.float64))
    shape = (len(values), len(off_axis))
    out = {k: np.full(shape, np.nan) for k in ("pst", "pst_se", "ratio", "ratio_se", "sec")}
    opts = TraceOptions(nee=nee, first_vertex_sampling=bool(nee), second_vertex_sampling=bool(nee),
                        vertex_lobe_sampling=bool(nee))
    label = material if isinstance(material, str) else repr(material)
    store = _point_store(checkpoint_dir, resume, {
        "sweep": "design_sweep", "parameter": parameter, "values": values, "off_axis": off_axis,
        "rays": int(n_rays), "seed": int(seed), "material": material, "base_params": base_params, "nee": bool(nee)})
    with (dask_client(workers, scheduler) if client is None else nullcontext(client)) as client:
        bar = progress_bar(total=len(values) * len(off_axis), desc=f"sweep {parameter}", unit="point",
                           enabled=progress)
        for i, v in enumerate(values):
            params = dict(base_params or {})
            params[parameter] = int(v) if parameter == "vane_count" else float(v)
            setup = None
            for j, a in enumerate(off_axis):
                k = i * len(off_axis) + j
                if restore_grid_point(store, k, out, i, j):  # finished by an earlier run of this sweep
                    bar.update()
                    continue
                if setup is None:  # built only when one of its points is still to trace
                    setup = tube_setup(material=material, **params)
                    area = _area(setup)
                bar.set_postfix_str(f"{parameter}={v:g}, {math.degrees(a):g} deg")
                t0 = time.perf_counter()
                res = trace(setup.scene, [setup.beam.source(a)], n_rays=int(n_rays),
                            seed=point_seed(seed, i * len(off_axis) + j), materials=setup.materials,
                            options=opts, client=client)
                out["sec"][i, j] = time.perf_counter() - t0
                t = res.detectors[setup.detector]
                e_in = setup.beam.irradiance_w_per_mm2(a)
                p_ent = setup.entrance.power_w(setup.beam, a)
                out["pst"][i, j], out["pst_se"][i, j] = t.power_w / area / e_in, t.stderr_w / area / e_in
                out["ratio"][i, j], out["ratio_se"][i, j] = t.power_w / p_ent, t.stderr_w / p_ent
                save_grid_point(store, k, out, i, j)
                bar.update()
        bar.close()
    return SweepResult(parameter, values, np.round(np.degrees(off_axis), 9), out["pst"], out["pst_se"],
                       out["ratio"], out["ratio_se"], out["sec"], int(n_rays), int(seed), label)


def _point_store(folder, resume: bool, fingerprint: dict):
    """The sweep's :class:`straylight.checkpoints.PointStore` in ``folder`` (None: no checkpoints)."""
    if folder is None:
        if resume:
            raise ValueError("resume needs a checkpoint folder")
        return None
    from straylight.checkpoints import PointStore

    return PointStore(folder, fingerprint, resume=resume)


def _area(setup) -> float:
    from straylight.analyses.pst import detector_area

    return detector_area(setup, setup.detector).area_mm2
