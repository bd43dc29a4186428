"""The forward thermal estimate on the main engine: every emitting side of a part is a
:class:`straylight.sources.SurfaceEmission` source (Kirchhoff: its band radiance times that side's
directional emissivity, cosine-weighted), traced by :func:`straylight.trace.trace` onto the
detectors with the engine's walk, next-event estimation, roulette, chunks and Execution.

Strata: each (traced sub-band, emitting side) is its own trace with the materials at the sub-band's
wavelength (``materials.wavelength.at_wavelength``) and rays in proportion to its emitted band power
Phi = pi B_band(T) A eps_h. The detector's power is the sum of the strata's estimates, its variance
the sum of theirs (independent: every trace draws its own engine chunks, ``Execution.first_chunk``
from one counter per run). A part's share (``by_part``) is the sum of its sides' strata.
Detectors count their front only (``OutputOptions(detector_sides="front")``), as the reverse
estimator's rays leave the front; ``mirror`` parts reflect ``ts.mirror_reflectance`` (1 - it is their
emissivity, model.SideTables).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from materials.wavelength import at_wavelength
from straylight.detectors import Disk
from straylight.execution import Execution
from straylight.rng import CHUNK_RAYS, n_chunks
from straylight.sources import SurfaceEmission
from straylight.stop_rule import Look, reliability
from straylight.thermal.model import split_rays


def emission_sources(ts, sides, radiance) -> list:
    """[(part, side, SurfaceEmission)] of every side that emits in a sub-band: ``sides``
    (model.SideTables at its wavelength), ``radiance`` (P,) B_band of each part's temperature
    (W m^-2 sr^-1). The front of every part, and the back of a one-sided part (model.ThermalScene.one_sided)."""
    out = []
    for p in range(ts.n_parts):
        for side in (0, 1) if ts.one_sided[p] else (0,):
            eps_h = sides.hemispherical(p, side)
            phi = math.pi * float(radiance[p]) * ts.part_area_mm2(p) * 1e-6 * eps_h
            if not phi > 0:
                continue
            sign = 1.0 if side == 0 else -1.0
            if p in ts.planes:
                disk = Disk.of_plane(ts.planes[p])
                src = SurfaceEmission(np.zeros((0, 3, 3)), np.zeros((0, 3)), sides.eps[p, side], phi,
                                      annulus=(disk.centre_mm, sign * disk.normal, math.sqrt(disk.r2_in),
                                               math.sqrt(disk.r2_out)))
            else:
                sel = ts.triangle_part == p
                src = SurfaceEmission(ts.triangles_mm[sel], sign * ts.normals[sel], sides.eps[p, side], phi)
            out.append((p, side, src))
    return out


@dataclass
class _Stratum:
    """The running sums of one (sub-band, emitting side): per-ray estimates x of its power on the detector."""

    part: int
    n: int = 0
    s1: float = 0.0
    s2: float = 0.0
    chunks: list = field(default_factory=list)  # (rays, sum x, sum x^2) per engine chunk

    def mean_var(self):
        if self.n < 2:
            return self.s1 / max(self.n, 1), (math.inf if self.n else 0.0)
        return self.s1 / self.n, max(self.s2 - self.s1 * self.s1 / self.n, 0.0) / (self.n * (self.n - 1.0))


class EngineForwardRun:
    """One detector's forward estimate on the engine, round after round (the interface of
    straylight.thermal.run's detector runs: ``round``, ``combined``, ``look``, ``rays``)."""

    def __init__(self, ts, bands, rad_sets, share, detector: str, seed: int, min_rays: int, threads: int,
                 chunk_counter: list):
        from straylight.trace import OutputOptions, PhysicsOptions, TraceOptions

        self.ts, self.bands, self.share, self.detector = ts, bands, share, detector
        self.seed, self.min_rays, self.threads, self.counter = int(seed), int(min_rays), int(threads), chunk_counter
        self.options = TraceOptions(output=OutputOptions(detector_sides="front"),
                                    physics=PhysicsOptions(mirror_reflectance=float(ts.mirror_reflectance)))
        self.sources, self.materials, self.strata = [], [], []
        for k, (_, _, lam) in enumerate(bands):
            srcs = emission_sources(ts, ts.sides_at(lam), rad_sets[k, 0])
            self.sources.append(srcs)
            self.materials.append({name: at_wavelength(m, lam * 1e3) for name, m in ts.materials.items()})
            self.strata.append([_Stratum(p) for p, _, _ in srcs])

    @property
    def rays(self) -> int:
        return sum(s.n for band in self.strata for s in band)

    def round(self, rays_now: int) -> None:
        """About ``rays_now`` more rays: shared by the sub-bands as the reverse run shares them, then by
        the emitting sides in proportion to their emitted power (each side at least 2)."""
        from straylight.trace import trace

        active = np.array([len(s) > 0 for s in self.sources])
        counts = split_rays(int(rays_now), np.where(active, self.share, 0.0), self.min_rays)
        for k, srcs in enumerate(self.sources):
            if counts[k] <= 0 or not srcs:
                continue
            per = split_rays(int(counts[k]), np.array([s.power_w for _, _, s in srcs]), 2)
            for stratum, (_, _, src), n in zip(self.strata[k], srcs, per):
                if n <= 0:
                    continue
                first = self.counter[0]
                self.counter[0] += n_chunks(int(n))
                res = trace(self.ts.scene, [src], int(n), seed=self.seed, materials=self.materials[k],
                            options=self.options, execution=Execution(threads=self.threads if self.threads > 1 else None,
                                                                      first_chunk=first))
                c1, c2 = res.chunks_of(self.detector)
                x1, x2 = n * np.asarray(c1, float), n * n * np.asarray(c2, float)  # per-ray estimates of Phi's share
                sizes = np.full(len(x1), float(CHUNK_RAYS))
                sizes[-1] = n - CHUNK_RAYS * (len(x1) - 1)
                stratum.n += int(n)
                stratum.s1 += float(x1.sum())
                stratum.s2 += float(x2.sum())
                stratum.chunks += list(zip(sizes.tolist(), x1.tolist(), x2.tolist()))

    def combined(self, c: int = 0):
        """(total, its stderr, per-part (P,), their stderrs): sums over the independent strata."""
        P = self.ts.n_parts
        per, per_var = np.zeros(P), np.zeros(P)
        for band in self.strata:
            for s in band:
                if s.n:
                    m, v = s.mean_var()
                    per[s.part] += m
                    per_var[s.part] += v
        return float(per.sum()), float(np.sqrt(per_var.sum())), per, np.sqrt(per_var)

    def look(self) -> Look:
        """The precision stop's view: the total's relative error, and the VOV and largest chunk share of
        the stratum that holds most of the variance."""
        tot, err, _, _ = self.combined()
        worst, best_var = None, -1.0
        chunks = 0
        for band in self.strata:
            for s in band:
                chunks += len(s.chunks)
                if s.n < 2 or not s.chunks:
                    continue
                var = s.mean_var()[1]
                if var > best_var:
                    n_c, t1, t2 = (np.array(x, dtype=np.float64) for x in zip(*s.chunks))
                    best_var, worst = var, reliability(t1, t2, s.n, chunk_rays=n_c)
        if worst is None or tot <= 0:
            return Look(self.rays, tot, float("nan"), float("nan"), float("nan"), chunks)
        return Look(self.rays, tot, err / tot, worst.vov, worst.max_chunk_share, chunks)
