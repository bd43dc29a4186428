"""Where thermal rays start: uniform points on parts (AreaSampler), cosine-weighted directions,
and emission directions with density eps(theta) cos(theta) / (pi eps_h)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from straylight.detectors import Disk
from straylight.sources import orthonormal_basis


def to_world(v, t, b, n):
    """Local (t, b, n) coordinates ``v`` (m, 3) to world directions."""
    return v[:, :1] * t + v[:, 1:2] * b + v[:, 2:3] * n


def cosine_directions(nrm, u2):
    """Cosine-weighted directions about unit normals ``nrm`` (n, 3) from uniforms (n, 2)."""
    r = np.sqrt(u2[:, 0])
    phi = 2 * np.pi * u2[:, 1]
    local = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(0.0, 1.0 - u2[:, 0]))], axis=1)
    t, b = orthonormal_basis(nrm)
    return to_world(local, t, b, nrm)


@dataclass(eq=False)
class AreaSampler:
    """Uniform points on a set of triangles (front normals kept)."""

    triangles: np.ndarray  # (k, 3, 3)
    normals: np.ndarray  # (k, 3)
    area_mm2: float
    cdf: np.ndarray

    disk: Disk | None = None  # an analytic plane part: sample its exact disk or annulus instead

    @classmethod
    def of_part(cls, ts, p: int) -> AreaSampler:
        sel = ts.triangle_part == p
        a = ts.areas_mm2[sel]
        return cls(ts.triangles_mm[sel], ts.normals[sel], ts.part_area_mm2(p), np.cumsum(a) / a.sum(),
                   Disk.of_plane(ts.planes[p]) if p in ts.planes else None)

    def sample(self, u3):
        """(points (n, 3), normals (n, 3)) from uniforms (n, 3)."""
        if self.disk is not None:
            from straylight.disk_sampling import sample_annulus  # a numba kernel: compiled on first use

            return sample_annulus(self.disk, u3[:, 1], u3[:, 2]), np.tile(self.disk.normal, (len(u3), 1))
        k = np.minimum(np.searchsorted(self.cdf, u3[:, 0], side="right"), len(self.cdf) - 1)
        s = np.sqrt(u3[:, 1])
        a, b = 1.0 - s, s * (1.0 - u3[:, 2])
        tri = self.triangles[k]
        p = a[:, None] * tri[:, 0] + b[:, None] * tri[:, 1] + (1.0 - a - b)[:, None] * tri[:, 2]
        return p, self.normals[k]


def emission_directions(eps_front, nrm, draws, rays, max_rounds: int = 1000):
    """Directions with density proportional to eps(theta) cos(theta) about ``nrm`` (n, 3), by
    rejection from cosine-weighted draws (accept with eps / max eps); ``eps_front``: table on a
    uniform grid of theta over [0, pi/2] (model.THETA_GRID). All rays of a part then carry the same weight.
    ``rays``: the rays' numbers in ``draws`` (straylight.rng.BatchDraws; ascending), whose streams the
    draws come from."""
    grid = np.linspace(0.0, np.pi / 2, len(eps_front))
    n = len(nrm)
    e_max = float(eps_front.max())
    out = np.zeros((n, 3))
    todo = np.arange(n)
    for _ in range(max_rounds):
        if len(todo) == 0:
            break
        u = draws.uniforms(rays[todo], 3)
        d = cosine_directions(nrm[todo], u[:, :2])
        cos = np.einsum("ij,ij->i", d, nrm[todo])
        e = np.interp(np.arccos(np.clip(cos, 0.0, 1.0)), grid, eps_front)
        ok = u[:, 2] * e_max < e
        out[todo[ok]] = d[ok]
        todo = todo[~ok]
    if len(todo):
        raise RuntimeError("emission sampling did not converge (emissivity nearly zero everywhere)")
    return out


def emission_rays(sampler: AreaSampler, eps_table, u3, draws, rays, back: bool = False):
    """(points, normals, directions) of rays emitted from ``sampler``'s front (its back: ``back``)
    with the emissivity table ``eps_table`` of that side, points from uniforms ``u3`` (n, 3) and
    directions drawn for ``rays`` from ``draws`` (:func:`emission_directions`)."""
    o, nrm = sampler.sample(u3)
    if back:
        nrm = -nrm
    return o, nrm, emission_directions(eps_table, nrm, draws, rays)
