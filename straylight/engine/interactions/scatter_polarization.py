"""Polarized scatter at a ``brdf_scatter`` vertex (CONTRACTS §6.3): the material's Mueller BRDF
``M`` (materials.polarized_brdf, in the incident s/p basis and the scattered (e1 = wo x n, e2))
acts on the arriving Stokes vector S (S0 = 1, frame e1 = s = d x n):

- scattered power: ``f = M[0] . S`` (M00 + M01 S1 + M02 S2 + M03 S3), for NEE toward the
  detectors and for the walk's sampled direction (weight x f_pol / M00: the material's own draw
  and pdf, which are the unpolarized ones, stay unbiased);
- the scattered ray carries ``M S / (M S)_0`` in the frame e1 (stored for its next interaction)
  where the material is polarizing; elsewhere it leaves unpolarized (its state goes stale).

Unpolarized rays on non-polarizing materials take the unpolarized path bit for bit. Under the
trace option ``polarization = "s"``/``"p"`` (every vertex evaluated for that polarization; the
reflectometer twin's mode) nothing here runs.
"""
from __future__ import annotations

import numpy as np

from materials.mueller import s_vector
from materials.polarized_brdf import is_polarizing, mueller_brdf
from materials.sampling import lazy_njit
from straylight.engine.interactions.stokes import active_state, incoming_stokes
from straylight.engine.material_groups import brdf_and_pdf, by_material, distinct
from straylight.engine.vec3 import dot_rows, take_rows


def _to_local(v, tangent, bitangent, nf):
    return np.stack([dot_rows(v, tangent), dot_rows(v, bitangent), dot_rows(v, nf)], axis=-1)


class Arriving:
    """The arriving polarization at a set of scatter vertices."""

    def __init__(self, st, S, s_local, polar_mat, frame, rays_ray, rays_depth):
        self.st = st
        self.S = S  # (n, 4) in the frame e1 = s
        self.s_local = s_local  # (n, 3) s in the vertex frames
        self.polar_mat = polar_mat  # (n,) bool: the vertex's material is polarizing
        self.polarized = np.any(S[:, 1:] != 0.0, axis=1)
        self.frame = frame
        self.ray = rays_ray
        self.depth = rays_depth

    def nee_evaluate(self, models):
        """NEE's ``evaluate(wi, wo, vertex)``: the unpolarized f and pdf, with f = M[0] . S where a
        polarized ray meets a polarizing material."""
        material = self.frame.material

        def evaluate(wi, wo, vertex):
            f = np.empty(len(wi))
            p = np.empty(len(wi))
            for rows, (fv, pv) in by_material(models, material[vertex], lambda model, rows:
                    brdf_and_pdf(model, wi[rows], wo[rows], "u")):
                f[rows] = fv
                p[rows] = pv
            use = np.flatnonzero(self.polarized[vertex] & self.polar_mat[vertex])
            if len(use):
                mv = material[vertex[use]]
                for k in distinct(mv):
                    g = use[mv == k]
                    v = vertex[g]
                    M, _ = mueller_brdf(models[k], wi[g], wo[g], self.s_local[v], first_row_only=True)
                    f[g] = np.einsum("nj,nj->n", M[:, 0, :], self.S[v])
            return f, p

        return evaluate

    def scatter(self, event, verts, wo_world):
        """Weight factors (n,) for the sampled directions; the scattered rays' states are stored."""
        ratio, use, S_out, e1 = self.scattered(event, verts, wo_world)
        if len(use):
            self.st.store(self.ray[use], self.depth[use], S_out, e1)
        return ratio

    def scattered(self, event, verts, wo_world, subset=None):
        """For the vertices ``subset`` (positions; default all) scattered into ``wo_world`` (one row
        each, at the event rows ``verts[subset]``): the weight factors (m,), and for those on a
        polarizing material, their positions ``use`` (into the subset) with the states S_out (k, 4)
        and frame vectors e1 (k, 3, world)."""
        sub = np.arange(len(self.S)) if subset is None else np.asarray(subset)
        ratio = np.ones(len(sub))
        use = np.flatnonzero(self.polar_mat[sub])
        if len(use) == 0:
            return ratio, use, np.zeros((0, 4)), np.zeros((0, 3))
        models = event.spec.materials
        at = sub[use]  # positions among this object's vertices
        nf = event.hits.facing_normal[np.asarray(verts)[at]]
        fr = self.frame
        wo = _to_local(wo_world[use], take_rows(fr.tangent, at), take_rows(fr.bitangent, at), nf)
        wi = take_rows(fr.wi_local, at)
        mv = fr.material[at]
        S_out = np.zeros((len(use), 4))
        e1 = np.zeros((len(use), 3))
        for k in distinct(mv):
            g = np.flatnonzero(mv == k)
            M, e1_loc = mueller_brdf(models[k], wi[g], wo[g], self.s_local[at[g]])
            scattered_rows(M, e1_loc, self.S, self.polarized, fr.tangent, fr.bitangent, nf, at[g], use[g], g,
                           ratio, S_out, e1)
        return ratio, use, S_out, e1


def scattered_rows(M, e1_loc, S, polarized, tangent, bitangent, nf, at, to, g, ratio, S_out, e1):
    """The rows ``g`` of :meth:`Arriving.scattered` after their Mueller BRDFs ``M`` (m, 4, 4) and local frame
    vectors ``e1_loc`` (m, 3): ``So = M S`` of the arriving states ``S[at]``, the weight ratios
    ``So_0 / M00`` (1 for an unpolarized arrival) into ``ratio[to]``, the states (``(1, 0, 0, 0)`` where
    ``So_0 <= 0``) into ``S_out[g]`` and the frame vectors (world) into ``e1[g]``. One compiled pass
    (:func:`_scattered_rows_loop`), :func:`scattered_rows_numpy`'s operations in its order (the same bits)."""
    if len(g):
        idx = (np.ascontiguousarray(i, np.int64) for i in (at, to, g))
        lazy_njit(_scattered_rows_loop, "numpy")(np.ascontiguousarray(M), np.ascontiguousarray(e1_loc), S, polarized,
                                                 tangent, bitangent, nf, *idx, ratio, S_out, e1)


def scattered_rows_numpy(M, e1_loc, S, polarized, tangent, bitangent, nf, at, to, g, ratio, S_out, e1):
    """:func:`scattered_rows` in vectorised numpy (the reference it is tested against)."""
    So = np.einsum("nij,nj->ni", M, S[at])
    m00 = M[:, 0, 0]
    pol = polarized[at]
    ratio[to] = np.where(pol, np.where(m00 > 0, So[:, 0] / np.where(m00 > 0, m00, 1.0), 0.0), 1.0)
    S_out[g] = np.where((So[:, 0] > 0)[:, None], So, np.array([1.0, 0, 0, 0]))
    e1[g] = (e1_loc[:, :1] * tangent[at] + e1_loc[:, 1:2] * bitangent[at]
             + e1_loc[:, 2:3] * nf[g])


def _scattered_rows_loop(M, e1_loc, S, polarized, tangent, bitangent, nf, at, to, g, ratio, S_out, e1):
    """:func:`scattered_rows_numpy` row by row: einsum's order of the four products,
    ``(M_i0 S_0 + M_i2 S_2) + (M_i1 S_1 + M_i3 S_3)``."""
    so = np.empty(4)
    for r in range(len(g)):
        a = at[r]
        for i in range(4):
            so[i] = (M[r, i, 0] * S[a, 0] + M[r, i, 2] * S[a, 2]) + (M[r, i, 1] * S[a, 1] + M[r, i, 3] * S[a, 3])
        m00 = M[r, 0, 0]
        if polarized[a]:
            ratio[to[r]] = so[0] / m00 if m00 > 0 else 0.0
        else:
            ratio[to[r]] = 1.0
        row = g[r]
        if so[0] > 0:
            for i in range(4):
                S_out[row, i] = so[i]
        else:
            S_out[row, 0] = 1.0
            S_out[row, 1] = 0.0
            S_out[row, 2] = 0.0
            S_out[row, 3] = 0.0
        for c in range(3):
            e1[row, c] = (e1_loc[r, 0] * tangent[a, c] + e1_loc[r, 1] * bitangent[a, c]) + e1_loc[r, 2] * nf[row, c]


def arriving(event, verts, frame):
    """:class:`Arriving` for the vertices ``verts`` (rows of the event), or None when nothing there
    can be polarized (no state in the batch, or no polarized ray and no polarizing material)."""
    spec = event.spec
    if spec.options.physics.polarization != "u":
        return None
    st = active_state(event)
    if st is None:
        return None
    polar_mat = np.array([is_polarizing(m) for m in spec.materials], bool)[frame.material]
    rays = event.rays
    d = take_rows(rays.direction, verts)
    nf = take_rows(event.hits.facing_normal, verts)
    s = s_vector(d, nf)
    S = incoming_stokes(st, rays.ray[verts], rays.depth[verts], d, s)
    if not (polar_mat.any() or np.any(S[:, 1:] != 0.0)):
        return None
    return Arriving(st, S, _to_local(s, frame.tangent, frame.bitangent, nf), polar_mat, frame, rays.ray[verts], rays.depth[verts])
