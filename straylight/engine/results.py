"""Stage: results. Batch results (per-chunk sums, in chunk order) are added up by
:class:`BatchTotals` and turned into a :class:`TraceResult` of tallies with standard errors, maps,
the power ledger and path records by :func:`build_result`."""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from straylight.detectors import IrradianceMap
from straylight.engine.ray_log import RayLog
from straylight.engine.roles import ROLE_DETECTOR
from straylight.engine.spec import TraceSpec
from straylight.paths import PathRecords, stderr_from_sums

if TYPE_CHECKING:
    from straylight.engine.plan import StrategyPlan


@dataclass(frozen=True)
class Tally:
    """A Monte Carlo estimate of a power and its standard error (1 sigma), in W."""

    power_w: float
    stderr_w: float

    def to_dict(self) -> dict:
        return {"power_w": self.power_w, "stderr_w": self.stderr_w}


@dataclass(frozen=True, eq=False)
class TraceResult:
    """Outcome of :func:`trace`; see docs/engine.md for each field."""

    n_rays: int
    seed: int
    emitted_w: float
    detectors: dict
    maps: dict
    absorbed: dict
    escaped: Tally
    incident: dict
    first_hit: dict
    ledger: dict
    paths: PathRecords | None
    segments: int
    shadow_rays: int
    detector_chunks: dict | None = None  # name -> (s1 (K,), s2 (K,)): per-chunk sums of the detector total
    strategies: StrategyPlan | None = None  # straylight.engine.plan.StrategyPlan: the requested strategies that ran, and why not the rest
    ray_log: RayLog | None = None  # the segments of the first OutputOptions.ray_log rays (None when off)
    #: detector name -> the power the beam puts on it straight, W, computed exactly by direct_area
    #: (straylight.engine.direct_area; inside ``detectors``' totals); None where that strategy did not run
    unscattered_w: dict | None = None

    def chunks_of(self, detector: str) -> tuple[np.ndarray, np.ndarray]:
        """(s1 (K,), s2 (K,)): the per-chunk sums of ``detector``'s total (every trace keeps them)."""
        if self.detector_chunks is None:
            raise ValueError("this result has no per-chunk detector sums")
        return self.detector_chunks[detector]

    def to_json_dict(self) -> dict:
        """CONTRACTS §4.3 keys, plus the ledger breakdown (its terms are already inside ``absorbed``)."""
        led = self.ledger
        return {
            "rays": self.n_rays,
            "seed": self.seed,
            "emitted_w": self.emitted_w,
            "detectors": {k: v.to_dict() for k, v in self.detectors.items()},
            "absorbed": {k: v.to_dict() for k, v in self.absorbed.items()},
            "escaped_w": self.escaped.power_w,
            "escaped_stderr_w": self.escaped.stderr_w,
            "ledger": {
                "note": "roulette, nee_exchange and truncated are already included in 'absorbed'; "
                        "emitted_w = sum(detectors) + sum(absorbed) + escaped_w",
                "roulette_w": led["roulette_w"].power_w,
                "roulette_stderr_w": led["roulette_w"].stderr_w,
                "nee_exchange_w": led["nee_exchange_w"].power_w,
                "truncated_w": led["truncated_w"].power_w,
                "balance_residual_w": led["balance_residual_w"],
                "detector_walk": {k: v.to_dict() for k, v in led["detector_walk"].items()},
                "absorbed_physical": {k: v.to_dict() for k, v in led["absorbed_physical"].items()},
            },
            "segments": self.segments,
            "shadow_rays": self.shadow_rays,
            **({"strategies": self.strategies.to_dict()} if self.strategies is not None else {}),
            **({"unscattered_w": dict(self.unscattered_w)} if self.unscattered_w is not None else {}),
        }


def build_result(spec: TraceSpec, detector_geometry, s1, s2, map_sums, paths_pieces, segments, shadow,
                 ray_log_pieces=()) -> TraceResult:
    """The :class:`TraceResult` of summed chunk sums (``detector_geometry``: DetectorGeometry per detector;
    ``ray_log_pieces``: the batches' ray-log pieces, straylight.engine.ray_log)."""
    N = spec.n_rays
    err = stderr_from_sums(s1, s2, N)
    names = spec.part_names
    P = len(names)
    det_parts = spec.detector_parts
    rows = spec.rows

    def tally(row):
        return Tally(float(s1[row]), float(err[row]))

    def summed(base):
        rows = slice(base, base + P)
        tot = float(s1[rows].sum())
        # per-ray sums of a whole block are not kept; the block's stderr adds per-part variances
        return Tally(tot, float(np.sqrt(np.sum(err[rows] ** 2))))

    detectors = {names[p]: tally(rows.detector_total + j) for j, p in enumerate(det_parts)}
    front = spec.options.output.detector_sides == "front"
    show_abs = [i for i in range(P) if spec.part_roles[i] != ROLE_DETECTOR or front]
    absorbed = {names[i]: tally(rows.ledger_absorbed + i) for i in show_abs}
    escaped = tally(rows.escaped)
    emitted = float(sum(s.power_w for s in spec.sources))
    residual = emitted - (sum(t.power_w for t in detectors.values()) + sum(t.power_w for t in absorbed.values())
                          + escaped.power_w)
    ledger = {
        "absorbed_physical": {names[i]: tally(rows.absorbed + i) for i in range(P)},
        "roulette": {names[i]: tally(rows.roulette + i) for i in range(P)},
        "nee_exchange": {names[i]: tally(rows.nee_exchange + i) for i in range(P)},
        "truncated": {names[i]: tally(rows.truncated + i) for i in range(P)},
        "detector_walk": {names[p]: tally(rows.detector_walk + j) for j, p in enumerate(det_parts)},
        "detector_nee": {names[p]: tally(rows.detector_nee + j) for j, p in enumerate(det_parts)},
        "detector_direct": {names[p]: tally(rows.detector_direct + j) for j, p in enumerate(det_parts)},
        "roulette_w": summed(rows.roulette),
        "nee_exchange_w": summed(rows.nee_exchange),
        "truncated_w": summed(rows.truncated),
        "balance_residual_w": float(residual),
    }
    maps = {}
    bins = tuple(int(b) for b in spec.options.output.map_bins)
    for j, p in enumerate(det_parts):
        geo = detector_geometry[j]
        m1, m2 = map_sums[j]
        eu, ev = geo.edges_mm(bins)
        maps[names[p]] = IrradianceMap(eu, ev, m1.reshape(bins), stderr_from_sums(m1, m2, N).reshape(bins),
                                       geo.origin_mm, geo.axis_u, geo.axis_v, geo.normal)
    paths = None
    if spec.options.output.record_paths:
        paths = PathRecords.concatenate(paths_pieces, names, N, int(spec.options.output.path_depth))
    return TraceResult(
        n_rays=N, seed=spec.seed, emitted_w=emitted, detectors=detectors, maps=maps, absorbed=absorbed,
        escaped=escaped,
        incident={names[i]: tally(rows.incident + i) for i in range(P)},
        first_hit={names[i]: tally(rows.first_hit + i) for i in range(P)},
        ledger=ledger, paths=paths, segments=int(segments), shadow_rays=int(shadow),
        ray_log=RayLog.concatenate(ray_log_pieces) if int(spec.options.output.ray_log) > 0 else None,
    )


class BatchTotals:
    """Running sums of batch results, added in chunk order (so the numbers do not depend on how
    the chunks were grouped or scheduled)."""

    def __init__(self, spec: TraceSpec):
        rows = spec.n_rows
        self.s1 = np.zeros(rows)
        self.s2 = np.zeros(rows)
        bins = tuple(int(b) for b in spec.options.output.map_bins)
        nb = bins[0] * bins[1]
        self.n_detectors = len(spec.detector_parts)
        self.map_sums = [(np.zeros(nb), np.zeros(nb)) for _ in range(self.n_detectors)]
        self.paths: list = []
        self.segments = 0
        self.shadow_rays = 0
        self.ray_log: list = []  # the batches' ray-log pieces (straylight.engine.ray_log), in chunk order
        self.detector_rows = spec.rows.detector_total + np.arange(self.n_detectors)
        self.chunk_s1: list = []  # per chunk: the detector totals' sums (reliability checks)
        self.chunk_s2: list = []

    def add(self, res: dict) -> int:
        """Add one batch result; returns its number of chunks."""
        for c in range(len(res["s1"])):
            self.s1 += res["s1"][c]
            self.s2 += res["s2"][c]
            self.chunk_s1.append(res["s1"][c][self.detector_rows])
            self.chunk_s2.append(res["s2"][c][self.detector_rows])
            for j in range(self.n_detectors):
                entry = res["maps"][c][j]
                if entry is not None:
                    self.map_sums[j][0][entry[0]] += entry[1]
                    self.map_sums[j][1][entry[0]] += entry[2]
        self.paths.append(res["paths"])
        self.segments += res["segments"]
        self.shadow_rays += res["shadow_rays"]
        if res.get("ray_log") is not None:
            self.ray_log.append(res["ray_log"])
        return len(res["s1"])

    def result(self, spec: TraceSpec, detector_geometry) -> "TraceResult":
        res = build_result(spec, detector_geometry, self.s1, self.s2, self.map_sums, self.paths, self.segments,
                           self.shadow_rays, self.ray_log)
        shape = (len(self.chunk_s1), self.n_detectors)  # (chunks, detectors); a scene may have no detector
        c1 = np.array(self.chunk_s1, dtype=np.float64).reshape(shape)
        c2 = np.array(self.chunk_s2, dtype=np.float64).reshape(shape)
        names = [spec.part_names[p] for p in spec.detector_parts]
        return replace(res, detector_chunks={n: (c1[:, j], c2[:, j]) for j, n in enumerate(names)})
