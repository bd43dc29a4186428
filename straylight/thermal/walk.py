"""The thermal walks' shared steps, in numpy over Embree: casting rays, the surface interaction
of a hit (scatter lobes, specular reflection, refraction: the branch rules of the engine's
``optical_surface``, unpolarized), emission sampling on parts, and Russian roulette.

Per event a ray draws ``EVENT_COLUMNS`` uniforms from its chunk's stream: 0 picks the branch
(lobes / specular / transmission), 1..3 go to the material's ``sample``, 4 to roulette, 5..7 to
next-event estimation. Streams: ``numpy.random.default_rng([seed, stream, chunk])``, chunks of
``CHUNK_RAYS`` rays, so results do not depend on how chunks are grouped (CONTRACTS §1).

Limits (docs/thermal.md): facet normals (no refinement onto analytic surfaces), unpolarized
(the mean of s and p at every Fresnel interface), no bulk absorption or bulk emission in
dielectrics, reverse walks use f(wi, wo) with wi and wo swapped (exact for reciprocal BRDFs).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from materials.flags import ComponentFlags, flags_of
from materials.smooth import reflect, refract

CHUNK_RAYS = 4096
EVENT_COLUMNS = 8
ROULETTE_W = 1e-2  # relative to the start weight: survive with probability w / ROULETTE_W
MAX_EVENTS = 100_000  # a bound, not a truncation: roulette ends the paths long before (mirror boxes need thousands)


def chunk_rng(seed: int, stream: int, chunk: int) -> np.random.Generator:
    return np.random.default_rng([int(seed), int(stream), int(chunk)])


@dataclass
class Hit:
    """Where the rays of one event ended (rows of the live rays; ``tri`` -1 = escaped)."""

    tri: np.ndarray
    part: np.ndarray
    point: np.ndarray  # (n, 3)
    cos: np.ndarray  # d . n (n the triangle's front normal): < 0 arriving on the front
    facing: np.ndarray  # (n, 3) normal turned toward the incoming ray

    @property
    def front(self) -> np.ndarray:
        return self.cos < 0

    @property
    def theta(self) -> np.ndarray:
        return np.arccos(np.clip(np.abs(self.cos), 0.0, 1.0))


def cast(ts, o, d) -> Hit:
    """First hits of rays (o, d); distances from the triangle planes in float64. A hit on an
    analytic plane part outside its exact annulus passes through (the mesh circumscribes it)."""
    tri = np.asarray(ts.intersector.first_triangle(o, d), dtype=np.int64)
    if ts.planes:
        o = np.array(o, dtype=np.float64)
        for _ in range(8):
            bad = _outside_planes(ts, tri, o, d)
            if not bad.any():
                break
            t = _plane_t(ts, tri[bad], o[bad], d[bad])
            o[bad] = o[bad] + (t + ts.eps_mm)[:, None] * d[bad]
            tri[bad] = np.asarray(ts.intersector.first_triangle(o[bad], d[bad]), dtype=np.int64)
    ok = tri >= 0
    k = np.where(ok, tri, 0)
    n = ts.normals[k]
    cos = np.einsum("ij,ij->i", d, n)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ts.plane_d[k] - np.einsum("ij,ij->i", n, o)) / cos
    t = np.where(ok & np.isfinite(t), np.maximum(t, 0.0), 0.0)
    point = o + t[:, None] * d
    facing = np.where((cos < 0)[:, None], n, -n)
    return Hit(tri=np.where(ok, tri, -1), part=np.where(ok, ts.triangle_part[k], -1), point=point, cos=cos,
               facing=facing)


def _plane_t(ts, tri, o, d):
    n = ts.normals[tri]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ts.plane_d[tri] - np.einsum("ij,ij->i", n, o)) / np.einsum("ij,ij->i", d, n)
    return np.where(np.isfinite(t), np.maximum(t, 0.0), 0.0)


def _outside_planes(ts, tri, o, d):
    """Rays whose hit lies on an analytic plane part's mesh but outside its exact annulus."""
    bad = np.zeros(len(tri), bool)
    hit = tri >= 0
    part = np.where(hit, ts.triangle_part[np.where(hit, tri, 0)], -1)
    for p, (v, a, r0, r1) in ts.planes.items():
        sel = np.flatnonzero(part == p)
        if len(sel) == 0:
            continue
        x = o[sel] + _plane_t(ts, tri[sel], o[sel], d[sel])[:, None] * d[sel] - v
        r = np.linalg.norm(x - np.outer(x @ a, a), axis=1)
        bad[sel] = (r > r1) | (r < r0)
    return bad


def frame(nrm):
    """Orthonormal tangents (t, b) for unit normals (n, 3) (Duff et al. 2017, branchless)."""
    sign = np.where(nrm[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + nrm[:, 2])
    b = nrm[:, 0] * nrm[:, 1] * a
    t = np.stack([1.0 + sign * nrm[:, 0] ** 2 * a, sign * b, -sign * nrm[:, 0]], axis=1)
    bb = np.stack([b, sign + nrm[:, 1] ** 2 * a, -nrm[:, 1]], axis=1)
    return t, bb


def to_local(v, t, b, n):
    return np.stack([np.einsum("ij,ij->i", v, t), np.einsum("ij,ij->i", v, b), np.einsum("ij,ij->i", v, n)], axis=1)


def to_world(v, t, b, n):
    return v[:, :1] * t + v[:, 1:2] * b + v[:, 2:3] * n


def cosine_directions(nrm, u2):
    """Cosine-weighted directions about unit normals ``nrm`` (n, 3) from uniforms (n, 2)."""
    r = np.sqrt(u2[:, 0])
    phi = 2 * np.pi * u2[:, 1]
    local = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(0.0, 1.0 - u2[:, 0]))], axis=1)
    t, b = frame(nrm)
    return to_world(local, t, b, nrm)


@dataclass
class Outgoing:
    direction: np.ndarray
    throughput: np.ndarray
    side: np.ndarray  # +1 leaves on the incident side, -1 crosses the surface
    delta: np.ndarray  # bool: a specular or refracted direction (NEE cannot reach it)


def interact(ts, sides, hit: Hit, rows, d, u) -> Outgoing:
    """Continuing hits ``rows`` (of ``hit``; surface or mirror parts) with incoming directions ``d``
    (n, 3) and uniforms ``u`` (n, EVENT_COLUMNS)."""
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
    t, b = frame(nf)
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


def roulette(w, w_ref, u):
    """Russian roulette below ``ROULETTE_W * w_ref``: survivors get that weight (unbiased)."""
    thr = ROULETTE_W * w_ref
    low = (w < thr) & (w > 0)
    w = w.copy()
    w[low] = np.where(u[low] * thr < w[low], thr[low] if np.ndim(thr) else thr, 0.0)
    return w


# ---------------------------------------------------------------- emission and area sampling


@dataclass(eq=False)
class AreaSampler:
    """Uniform points on a set of triangles (front normals kept)."""

    triangles: np.ndarray  # (k, 3, 3)
    normals: np.ndarray  # (k, 3)
    area_mm2: float
    cdf: np.ndarray

    plane: tuple | None = None  # (vertex, unit axis, r0, r1): sample the exact annulus instead

    @classmethod
    def of_part(cls, ts, p: int) -> AreaSampler:
        sel = ts.triangle_part == p
        a = ts.areas_mm2[sel]
        return cls(ts.triangles_mm[sel], ts.normals[sel], ts.part_area_mm2(p), np.cumsum(a) / a.sum(),
                   ts.planes.get(p))

    def sample(self, u3):
        """(points (n, 3), normals (n, 3)) from uniforms (n, 3)."""
        if self.plane is not None:
            v, a, r0, r1 = self.plane
            t, b = frame(a[None, :])
            r = np.sqrt(r0 * r0 + u3[:, 1] * (r1 * r1 - r0 * r0))
            phi = 2 * np.pi * u3[:, 2]
            p = v + (r * np.cos(phi))[:, None] * t + (r * np.sin(phi))[:, None] * b
            return p, np.broadcast_to(a, p.shape).copy()
        k = np.minimum(np.searchsorted(self.cdf, u3[:, 0], side="right"), len(self.cdf) - 1)
        s = np.sqrt(u3[:, 1])
        a, b = 1.0 - s, s * (1.0 - u3[:, 2])
        tri = self.triangles[k]
        p = a[:, None] * tri[:, 0] + b[:, None] * tri[:, 1] + (1.0 - a - b)[:, None] * tri[:, 2]
        return p, self.normals[k]


def emission_directions(eps_front, nrm, rng, max_rounds: int = 1000):
    """Directions with density proportional to eps(theta) cos(theta) about ``nrm`` (n, 3), by
    rejection from cosine-weighted draws (accept with eps / max eps); ``eps_front``: table on a
    uniform grid of theta over [0, pi/2] (model.THETA_GRID). All rays of a part then carry the same weight."""
    grid = np.linspace(0.0, np.pi / 2, len(eps_front))
    n = len(nrm)
    e_max = float(eps_front.max())
    out = np.zeros((n, 3))
    todo = np.arange(n)
    for _ in range(max_rounds):
        if len(todo) == 0:
            break
        u = rng.random((len(todo), 3))
        d = cosine_directions(nrm[todo], u[:, :2])
        cos = np.einsum("ij,ij->i", d, nrm[todo])
        e = np.interp(np.arccos(np.clip(cos, 0.0, 1.0)), grid, eps_front)
        ok = u[:, 2] * e_max < e
        out[todo[ok]] = d[ok]
        todo = todo[~ok]
    if len(todo):
        raise RuntimeError("emission sampling did not converge (emissivity nearly zero everywhere)")
    return out
