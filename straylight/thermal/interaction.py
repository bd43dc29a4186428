"""The surface interaction of a thermal walk's hit, in numpy: scatter lobes, specular reflection,
refraction (the branch rules of the engine's ``optical_surface``, unpolarized: the mean of s and p),
chosen by the material's declared flags (materials.flags)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from materials.flags import ComponentFlags, flags_of
from materials.smooth import reflect, refract
from straylight.sources import orthonormal_basis


def to_local(v, t, b, n):
    return np.stack([np.einsum("ij,ij->i", v, t), np.einsum("ij,ij->i", v, b), np.einsum("ij,ij->i", v, n)], axis=1)


def to_world(v, t, b, n):
    return v[:, :1] * t + v[:, 1:2] * b + v[:, 2:3] * n


@dataclass
class Outgoing:
    direction: np.ndarray
    throughput: np.ndarray
    side: np.ndarray  # +1 leaves on the incident side, -1 crosses the surface
    delta: np.ndarray  # bool: a specular or refracted direction (NEE cannot reach it)


def interact(ts, sides, hit, rows, d, u) -> Outgoing:
    """Continuing hits ``rows`` (of ``hit``, a straylight.thermal.walk.Hit; surface or mirror parts)
    with incoming directions ``d`` (n, 3) and uniforms ``u`` (n, EVENT_COLUMNS)."""
    n = len(rows)
    out = Outgoing(np.zeros((n, 3)), np.zeros(n), np.ones(n), np.zeros(n, bool))
    part = hit.part[rows]
    nf = hit.facing[rows]
    side = np.where(hit.front[rows], 0, 1)
    mirror = ts.is_role("mirror")[part]
    if mirror.any():
        out.direction[mirror] = reflect(d[mirror], nf[mirror])
        out.throughput[mirror] = ts.mirror_reflectance
        out.delta[mirror] = True
    surf = np.flatnonzero(~mirror)
    if len(surf) == 0:
        return out
    idx = sides.material_index[part[surf], side[surf]]
    for key in np.unique(idx):  # one call per material and side (a dielectric's back differs)
        for back in (0, 1):
            sel = surf[(idx == key) & (side[surf] == back)]
            if len(sel):
                _interact_material(sides.models[key], back == 1, d[sel], nf[sel], u[sel], out, sel)
    return out


def _interact_material(m, back, d, nf, u, out, sel):
    """By the material's declared flags (materials.flags): scatter lobes only, or a smooth interface
    (specular, and refraction when it transmits) with lobes, branched by expected power."""
    t, b = orthonormal_basis(nf)
    wi = to_local(-d, t, b, nf)
    flags = flags_of(m)
    coef = m.smooth_coefficients(wi[:, 2], back=bool(back) and bool(flags & ComponentFlags.DELTA_TRANSMISSION)) \
        if flags & ComponentFlags.DELTA else None
    if coef is None:  # scatter lobes only
        s = m.sample(wi, u[:, 1:4], "u")
        out.direction[sel] = to_world(s.wo, t, b, nf)
        out.throughput[sel] = np.where(s.wo[:, 2] > 0, s.weight, 0.0)
        return
    theta = np.arccos(np.clip(wi[:, 2], 0.0, 1.0))
    rho = m.lobe_reflectance(theta, "u")
    R = coef.reflectance("u")
    T = coef.transmittance("u")
    tot = rho + R + T
    x = u[:, 0] * tot
    lobe = x < rho
    spec = ~lobe & (x < rho + R)
    trans = ~lobe & ~spec & (T > 0)
    thr = np.zeros(len(d))
    dirs = np.tile(nf[:1] * 0, (len(d), 1))
    if lobe.any():
        s = m.sample(wi[lobe], u[lobe, 1:4], "u")
        dirs[lobe] = to_world(s.wo, t[lobe], b[lobe], nf[lobe])
        thr[lobe] = np.where(s.wo[:, 2] > 0, s.weight * tot[lobe] / rho[lobe], 0.0)
    if spec.any():
        dirs[spec] = reflect(d[spec], nf[spec])
        thr[spec] = tot[spec]
    if trans.any():
        dirs[trans] = refract(d[trans], nf[trans], coef.eta[trans], coef.cos_t[trans])
        thr[trans] = tot[trans]
    out.direction[sel] = dirs
    out.throughput[sel] = thr
    out.side[sel] = np.where(trans, -1.0, 1.0)
    out.delta[sel] = spec | trans
