"""Design sweep: PST at a few off-axis angles while one tube parameter varies.

Each design value rebuilds the CadQuery tube (``geometry.parts.tube.TubeParams``) and
traces the beam at every angle; each (design, angle) point has its own seed derived from
the user's seed, so points are independent and the sweep is reproducible.
"""
from __future__ import annotations

import csv
import json
import math
import time
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import atomicio

from straylight.analyses.pst import dask_client, point_seed
from straylight.checkpoints import restore_grid_point, save_grid_point
from straylight.progress import progress_bar

PARAMETER_LABELS = {
    "vane_count": "number of vanes",
    "vane_inner_radius_mm": "vane hole radius (mm)",
    "vane_thickness_mm": "vane thickness (mm)",
    "vane_bevel_deg": "vane bevel (deg)",
    "length_mm": "tube length (mm)",
}


@dataclass(frozen=True, eq=False)
class SweepResult:
    """PST over (design value, off-axis angle); arrays are (n_values, n_angles)."""

    parameter: str
    values: np.ndarray
    off_axis_deg: np.ndarray
    pst: np.ndarray
    pst_stderr: np.ndarray
    entrance_ratio: np.ndarray
    entrance_ratio_stderr: np.ndarray
    seconds: np.ndarray
    rays: int
    seed: int
    material: str

    def rows(self) -> list[dict]:
        return [{self.parameter: float(v), "off_axis_deg": float(a), "pst": float(self.pst[i, j]),
                 "pst_stderr": float(self.pst_stderr[i, j]), "entrance_ratio": float(self.entrance_ratio[i, j]),
                 "entrance_ratio_stderr": float(self.entrance_ratio_stderr[i, j]), "rays": self.rays,
                 "seconds": float(self.seconds[i, j])}
                for i, v in enumerate(self.values) for j, a in enumerate(self.off_axis_deg)]

    def to_json_dict(self) -> dict:
        return {"parameter": self.parameter, "values": [float(v) for v in self.values],
                "off_axis_deg": [float(a) for a in self.off_axis_deg], "rays_per_point": self.rays,
                "seed": self.seed, "material": self.material, "points": self.rows()}

    def write_json(self, path) -> Path:
        path = Path(path)
        atomicio.write_text(path, json.dumps(self.to_json_dict(), indent=2))
        return path

    def write_csv(self, path) -> Path:
        path = Path(path)
        rows = self.rows()
        with atomicio.atomic_open(path, "w") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
        return path

    def best(self, angle_index: int = -1) -> float:
        """Design value with the lowest PST at one angle (ties: the first)."""
        return float(self.values[int(np.nanargmin(self.pst[:, angle_index]))])

    def plot(self, path=None, ax=None):
        """PST vs the design parameter, one line per off-axis angle, log y, 1-sigma bars."""
        import matplotlib.pyplot as plt

        own = ax is None
        if own:
            fig, ax = plt.subplots(figsize=(7, 4.5), dpi=120)
        for j, a in enumerate(self.off_axis_deg):
            y, e = self.pst[:, j], self.pst_stderr[:, j]
            pos = y > 0
            ax.errorbar(self.values[pos], y[pos], yerr=np.minimum(e[pos], 0.999 * y[pos]), fmt="o-", ms=4,
                        capsize=3, label=f"{a:g} deg off axis")
            if np.any(~pos):
                ax.plot(self.values[~pos], np.zeros((~pos).sum()), "v", mfc="none", ms=7,
                        transform=ax.get_xaxis_transform(), clip_on=False, color=ax.lines[-1].get_color(),
                        label=f"{a:g} deg: zero detected")
        ax.set_yscale("log")
        ax.set_xlabel(PARAMETER_LABELS.get(self.parameter, self.parameter))
        ax.set_ylabel("PST = E_detector / E_input")
        if self.parameter == "vane_count":
            ax.set_xticks(self.values)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
        ax.set_title(f"Design sweep: {PARAMETER_LABELS.get(self.parameter, self.parameter)}\n"
                     f"coating {self.material}; {self.rays:.2g} rays per point, 1-sigma error bars", fontsize=10)
        if own:
            fig.tight_layout()
            if path is not None:
                atomicio.write_figure(fig, path)
                plt.close(fig)
        return ax


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
