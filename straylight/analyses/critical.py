"""Critical and illuminated objects, and the parts that are both.

*Illuminated objects* are the parts the source lights directly: a forward trace of the
beam, tallying the power whose first event is on each part (``first_hit``). *Critical
objects* are the parts the detector sees: by reciprocity, a Lambertian source of unit
power spread uniformly over the detector's sensitive side, traced in reverse; the power
whose first event is on a part is the detector-to-part view factor F(det -> part), the
fraction of the detector's projected solid angle the part fills. A part that is both lit
and seen can send light to the detector with a single scatter; the ranking score is
``illuminated fraction x view factor`` (the first-order coupling up to the part's BRDF).
The ``*_any`` columns count power arriving by any path (``incident``), e.g. parts seen
only through a mirror.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

import atomicio
from straylight.analyses.grid import point_seed
from straylight.analyses.pst import detector_name
from straylight.analyses.tables import ResultFiles, TableRepr
from straylight.execution import Execution, as_execution
from straylight.trace import EstimatorOptions, TraceOptions, trace


@dataclass(frozen=True, eq=False)
class LambertianPart:
    """A source emitting a cosine distribution from every triangle of a part, uniform per area.

    triangles_mm : (m, 3, 3); the emitting side is the one the triangle normal points to
    (for ``both_sides``, each ray picks a side with probability 1/2). ``offset_mm`` moves the
    origins off the surface so the first intersection is not the part itself.
    """

    triangles_mm: np.ndarray
    power_w: float = 1.0
    both_sides: bool = False
    offset_mm: float = 1e-4

    def __post_init__(self):
        tri = np.asarray(self.triangles_mm, dtype=np.float64)
        cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        twice = np.linalg.norm(cross, axis=1)
        if twice.sum() <= 0:
            raise ValueError("LambertianPart: the part has zero area")
        object.__setattr__(self, "triangles_mm", tri)
        object.__setattr__(self, "_normals", cross / np.where(twice > 0, twice, 1.0)[:, None])
        cdf = np.cumsum(twice) / twice.sum()
        cdf[-1] = 1.0
        object.__setattr__(self, "_cdf", cdf)

    def emit(self, u):
        """u : (n, 4) uniforms -> (origins (n, 3), dirs (n, 3)); deterministic in u."""
        from straylight.sources import orthonormal_basis

        u = np.asarray(u, dtype=np.float64)
        # u0 picks the triangle (by area) and is re-used, rescaled, for the side
        k = np.minimum(np.searchsorted(self._cdf, u[:, 0], side="right"), len(self._cdf) - 1)
        lo = np.where(k > 0, self._cdf[np.maximum(k - 1, 0)], 0.0)
        frac = (u[:, 0] - lo) / np.maximum(self._cdf[k] - lo, 1e-300)
        n = self._normals[k]
        if self.both_sides:  # the low half of frac picks the front side; rescale it back to [0, 1)
            front = frac < 0.5
            n = np.where(front[:, None], n, -n)
            frac = np.where(front, 2 * frac, 2 * frac - 1)
        tri = self.triangles_mm[k]
        # uniform point on the triangle from (u1, frac) (square-root warp)
        s = np.sqrt(np.clip(u[:, 1], 0, 1))
        b0, b1 = 1 - s, s * (1 - frac)
        pts = tri[:, 0] * b0[:, None] + tri[:, 1] * b1[:, None] + tri[:, 2] * (1 - b0 - b1)[:, None]
        t, b = orthonormal_basis(n)
        r = np.sqrt(u[:, 2])
        phi = 2 * np.pi * u[:, 3]
        z = np.sqrt(np.maximum(0.0, 1 - r * r))
        d = (r * np.cos(phi))[:, None] * t + (r * np.sin(phi))[:, None] * b + z[:, None] * n
        return pts + self.offset_mm * n, d

    def bounds_mm(self):
        pts = self.triangles_mm.reshape(-1, 3)
        return np.stack([pts.min(axis=0), pts.max(axis=0)])


@dataclass(frozen=True)
class ObjectRow:
    part: str
    illuminated: float
    illuminated_stderr: float
    view_factor: float
    view_factor_stderr: float
    illuminated_any: float
    seen_any: float
    score: float
    score_stderr: float


@dataclass(frozen=True, eq=False)
class CriticalReport(TableRepr, ResultFiles):
    """Per-part fractions; ``ranking`` lists the parts both illuminated and critical, best first.

    rows : every non-detector part (fractions of the source power / of the detector's emission)
    """

    rows: list
    ranking: list
    detector: str
    rays: int
    off_axis_deg: float

    @property
    def critical(self) -> list:
        return [r.part for r in sorted(self.rows, key=lambda r: -r.view_factor) if r.view_factor > 0]

    @property
    def illuminated(self) -> list:
        return [r.part for r in sorted(self.rows, key=lambda r: -r.illuminated) if r.illuminated > 0]

    def to_json_dict(self) -> dict:
        return {"detector": self.detector, "rays": self.rays, "off_axis_deg": self.off_axis_deg,
                "critical": self.critical, "illuminated": self.illuminated,
                "both_ranked": [r.part for r in self.ranking],
                "parts": [r.__dict__ for r in self.rows]}

    def to_pandas(self):
        """Every part as a pandas DataFrame (columns of critical.csv, by decreasing score; pandas is optional)."""
        from straylight.analyses.tables import data_frame

        return data_frame([r.__dict__ for r in sorted(self.rows, key=lambda r: -r.score)],
                          tuple(ObjectRow.__dataclass_fields__))

    def csv_table(self) -> tuple:
        """critical.csv: every part, by decreasing score."""
        return list(ObjectRow.__dataclass_fields__), [r.__dict__ for r in sorted(self.rows, key=lambda r: -r.score)]

    def markdown(self) -> str:
        lines = [f"Critical (seen from `{self.detector}`) and illuminated (lit by the beam at "
                 f"{self.off_axis_deg:g} deg) parts; {self.rays} rays each way.", "",
                 "| rank | part | illuminated fraction | view factor det -> part | score | lit (any path) | "
                 "seen (any path) |", "|---:|---|---:|---:|---:|---:|---:|"]
        ranked = self.ranking + [r for r in sorted(self.rows, key=lambda r: -(r.illuminated + r.view_factor))
                                 if r not in self.ranking]
        for i, r in enumerate(ranked, start=1):
            rank = str(i) if r in self.ranking else "-"
            lines.append(f"| {rank} | {r.part} | {r.illuminated:.3e} +- {r.illuminated_stderr:.1e} | "
                         f"{r.view_factor:.3e} +- {r.view_factor_stderr:.1e} | {r.score:.2e} | "
                         f"{r.illuminated_any:.2e} | {r.seen_any:.2e} |")
        return "\n".join(lines) + "\n"

    def plot(self, path=None):
        """Scatter of view factor vs illuminated fraction per part (log-log), both-ranked parts labelled."""
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(7, 5), dpi=120)
        rows = [r for r in self.rows if r.illuminated > 0 and r.view_factor > 0]
        floor_x = min([r.illuminated for r in rows], default=1e-6) / 10
        floor_y = min([r.view_factor for r in rows], default=1e-6) / 10
        for r in self.rows:
            x = r.illuminated if r.illuminated > 0 else floor_x
            y = r.view_factor if r.view_factor > 0 else floor_y
            both = r.illuminated > 0 and r.view_factor > 0
            ax.errorbar(x, y, xerr=min(r.illuminated_stderr, 0.99 * x) if both else None,
                        yerr=min(r.view_factor_stderr, 0.99 * y) if both else None,
                        fmt="o" if both else "x", color="C3" if both else "0.6", capsize=2)
            ax.annotate(r.part, (x, y), fontsize=7, xytext=(4, 3), textcoords="offset points")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("illuminated: fraction of beam power first hitting the part")
        ax.set_ylabel("critical: view factor detector -> part")
        ax.set_title(f"Critical vs illuminated parts at {self.off_axis_deg:g} deg "
                     "(grey x: zero on one axis, drawn at the floor)", fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        fig.tight_layout()
        if path is not None:
            atomicio.write_figure(fig, path)
            plt.close(fig)
        return ax


def critical_objects(setup, off_axis: float = 0.0, azimuth: float = 0.0, n_rays: int = 100_000, seed: int = 0,
                     execution: Execution | None = None) -> CriticalReport:
    """Forward trace of the beam and reverse trace from the detector; see the module docstring.
    ``execution``: where both traces run (one dask cluster for the two when it names workers or a
    scheduler) and whether to show progress."""
    det = detector_name(setup.scene, setup.detector)
    part = setup.scene.part(det)
    both = bool(getattr(part, "meta", {}).get("kind") == "solid")
    opts = TraceOptions(estimator=EstimatorOptions(nee=False))
    src = LambertianPart(part.vertices_mm[part.faces], power_w=1.0, both_sides=both)
    with as_execution(execution).opened() as ex:
        fwd = trace(setup.scene, [setup.beam.source(off_axis, azimuth)], n_rays=int(n_rays),
                    seed=point_seed(seed, 0), materials=setup.materials, options=opts, execution=ex)
        rev = trace(setup.scene, [src], n_rays=int(n_rays), seed=point_seed(seed, 1), materials=setup.materials,
                    options=opts, execution=ex)
    rows = []
    for name in setup.scene.part_names:
        if setup.scene.part(name).role == "detector":
            continue
        il, vf = fwd.first_hit[name], rev.first_hit[name]
        i, ie = il.power_w / fwd.emitted_w, il.stderr_w / fwd.emitted_w
        v, ve = vf.power_w / rev.emitted_w, vf.stderr_w / rev.emitted_w
        score = i * v
        score_se = math.hypot(ie * v, ve * i)  # independent traces: first-order error propagation
        rows.append(ObjectRow(name, i, ie, v, ve, fwd.incident[name].power_w / fwd.emitted_w,
                              rev.incident[name].power_w / rev.emitted_w, score, score_se))
    ranking = sorted([r for r in rows if r.score > 0], key=lambda r: -r.score)
    return CriticalReport(rows, ranking, det, int(n_rays), math.degrees(off_axis))
