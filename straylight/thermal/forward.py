"""Forward thermal estimator: emission from every part at a temperature, with next-event
estimation (NEE) toward the detector at every vertex.

A ray picks an emitting side (every part's front; also the back of a one-sided part) with
probability Phi_j / Phi (Phi_j = pi B_band(T_j) A_j eps_h,j, that side's emitted band power), a
uniform point of it and a direction with density
eps(theta) cos(theta) / (pi eps_h) (exact, by rejection: straylight.thermal.sampling), so every ray
carries Phi. NEE joins each vertex to a uniform point y of the detector's front (area A_d)::

    emission vertex:  W eps(theta) cos_x cos_d A_d / (pi eps_h r^2)       (the emission density)
    scatter vertex:   W f(wi, wo) cos_x cos_d A_d / r^2                   (the material's lobes)

and the walk's own detector hits count only after a specular or refracted event (the paths NEE
cannot make), so nothing is counted twice. Unbiased; compared with the reverse estimator in
benchmarks/thermal.py.
"""
from __future__ import annotations

import numpy as np

from straylight.sources import orthonormal_basis
from straylight.thermal.interaction import to_local
from straylight.thermal.sampling import AreaSampler, emission_rays
from straylight.thermal.walk import walk


class ForwardEstimator:
    """Batch function ``(sides, radiance (P,), draws) -> (per part (P, n), total (1, n))``: the per-ray
    power estimates of a batch of whole chunks (``draws``: straylight.rng.BatchDraws) for detector
    part ``det`` whose receiving front is ``det_sampler``."""

    def __init__(self, ts, det: int, det_sampler: AreaSampler):
        self.ts = ts
        self.det = det
        self.det_sampler = det_sampler
        self.samplers = {p: AreaSampler.of_part(ts, p) for p in range(ts.n_parts)}  # made once: batches share them

    def __call__(self, sides, radiance, draws):
        ts = self.ts
        P = ts.n_parts
        n = draws.n_rays
        # emitting sides: every part's front, and the back of a one-sided part (model.ThermalScene.one_sided)
        src = [(p, 0) for p in range(P)] + [(p, 1) for p in range(P) if ts.one_sided[p]]
        eps_h = np.array([sides.hemispherical(p, side) for p, side in src])
        phi = np.array([np.pi * radiance[p] * ts.part_area_mm2(p) * 1e-6 * e for (p, _), e in zip(src, eps_h)])
        total = float(phi.sum())
        x = np.zeros(n)
        if total <= 0:
            return np.zeros((P, n)), np.zeros((1, n))
        which = np.minimum(np.searchsorted(np.cumsum(phi) / total, draws.all(1)[:, 0], side="right"), len(src) - 1)
        emitter = np.array([p for p, _ in src])[which]
        side = np.array([q for _, q in src])[which]
        o = np.zeros((n, 3))
        nrm = np.zeros((n, 3))
        d = np.zeros((n, 3))
        u3 = draws.all(3)
        for i in np.unique(which):
            p, q = src[i]
            sel = np.flatnonzero(which == i)
            o[sel], nrm[sel], d[sel] = emission_rays(self.samplers[p], sides.eps[p, q], u3[sel], draws, sel,
                                                     back=q == 1)
        # NEE from the emission points
        cos_x, cos_d, r2, ok, _ = self._connect(o, nrm, draws.all(3))
        th = np.arccos(np.clip(cos_x, 0.0, 1.0))
        e = sides.emissivity(emitter, side, th)
        with np.errstate(divide="ignore", invalid="ignore"):
            x += np.where(ok, total * e * cos_x * cos_d * self.det_sampler.area_mm2 / (np.pi * eps_h[which] * r2), 0.0)

        def pickup(ev):  # the walk's own detector hits after a delta branch, then NEE from the scatter vertices
            hit = ev.hit
            on_det = ev.alive & (np.where(ev.alive, hit.part, 0) == self.det) & hit.front & ev.delta
            np.add.at(x, ev.ray[on_det], ev.w[on_det])
            self._nee_scatter(sides, hit, ev.cont, ev.d, ev.w, ev.ray, ev.U, x)

        walk(ts, sides, draws, o, nrm, d, np.full(n, total), pickup, w_ref=total)
        per = np.zeros((P, n))
        per[emitter, np.arange(n)] = x
        return per, x[None, :]

    def _connect(self, o, nrm_x, u3):
        """Shadow rays from points ``o`` (facing normals ``nrm_x``) to uniform detector points:
        (cos at x, cos at the detector, r^2, unblocked and front-to-front, unit directions)."""
        ts = self.ts
        y, ny = self.det_sampler.sample(u3)
        v = y - o
        r2 = np.einsum("ij,ij->i", v, v)
        r = np.sqrt(r2)
        with np.errstate(divide="ignore", invalid="ignore"):
            w = v / r[:, None]
        cos_x = np.einsum("ij,ij->i", w, nrm_x)
        cos_d = -np.einsum("ij,ij->i", w, ny)
        ok = (cos_x > 0) & (cos_d > 0) & (r > 2 * ts.eps_mm)
        idx = np.flatnonzero(ok)
        if len(idx):
            start = o[idx] + ts.eps_mm * nrm_x[idx]
            blocked = ts.intersector.occluded(start, w[idx], r[idx] - 3 * ts.eps_mm)
            ok[idx[blocked]] = False
        return cos_x, cos_d, r2, ok, w

    def _nee_scatter(self, sides, hit, cont, d, w, ray, U, x):
        """NEE from scatter vertices of surface parts with lobes (their f toward the detector)."""
        ts = self.ts
        part = hit.part[cont]
        surf = ts.is_role("surface")[part]
        rows = cont[surf]
        if len(rows) == 0:
            return
        nf = hit.facing[rows]
        cos_x, cos_d, r2, ok, wdir = self._connect(hit.point[rows], nf, U[rows, 5:8])
        idx = np.flatnonzero(ok)
        if len(idx) == 0:
            return
        rr = rows[idx]
        side = np.where(hit.front[rr], 0, 1)
        p = hit.part[rr]
        t, b = orthonormal_basis(nf[idx])
        wi = to_local(-d[rr], t, b, nf[idx])
        wo = to_local(wdir[idx], t, b, nf[idx])
        f = np.zeros(len(rr))
        mat = sides.material_index[p, side]
        for key in np.unique(mat):
            sel = np.flatnonzero(mat == key)
            f[sel] = sides.models[key].brdf(wi[sel], wo[sel], "u")
        contrib = w[rr] * f * cos_x[idx] * cos_d[idx] * self.det_sampler.area_mm2 / r2[idx]
        np.add.at(x, ray[rr], contrib)
