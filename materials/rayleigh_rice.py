"""The Rayleigh-Rice (first-order vector perturbation) Jones matrix of a slightly rough surface,
written with field vectors so that it holds in any s/p basis, and the polarized K-correlation BRDF.

Scattered amplitude for incident polarization a into scattered polarization b (reciprocity form
of the small-perturbation method; Tsang, Kong & Ding, *Scattering of Electromagnetic Waves*
vol. 1 §? and Germer, Appl. Opt. 36, 8798 (1997), whose amplitudes it reproduces)::

    J_ba = (eps - 1) / (4 cos_i cos_r) [E_a . E_b]_eps,
    [E . F]_eps = E_x F_x + E_y F_y + eps E_z F_z,

with ``E_a`` the field just inside the substrate set up by a unit incident wave of polarization a,
and ``E_b`` the field inside set up by a unit wave arriving from the scattering direction (along
``-wo``) with polarization b. Inside fields from Fresnel (:func:`materials.fresnel.fresnel_amplitudes`,
s = k x z, p = k x s on both sides). In the plane of incidence this gives Germer's ss, pp (times -1,
a common phase) and vanishing cross terms; out of it |J| equals |ss|, |sp|, |ps|, |pp| (checked in
tests/materials/test_rayleigh_rice_mueller.py), and the relative phases (which carry S2 and S3)
follow from the vectors rather than from a sign convention.

The BRDF is ``f_ba = (16 pi^2 / lambda^4) cos_i cos_r |J_ba|^2 S2(f)`` (PHYSICS §1), so the
K-correlation lobe's Mueller matrix is ``M = f_u jones_to_mueller(J) / M00(J)``.
"""
from __future__ import annotations

import numpy as np

from materials.mueller import jones_to_mueller, norm_rows

Z = np.array([0.0, 0.0, 1.0])


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def s_basis(k, fallback=None) -> np.ndarray:
    """s = k x z normalised for propagation directions k (n, 3) in the sample frame; along the
    normal, ``fallback`` (n, 3) (unit, normal to k) or the x-based rule of materials.mueller.s_vector."""
    z0, z1, z2 = Z  # np.cross(k, Z), its products and differences written out (the same bits)
    s = np.stack([k[:, 1] * z2 - k[:, 2] * z1, k[:, 2] * z0 - k[:, 0] * z2, k[:, 0] * z1 - k[:, 1] * z0], axis=-1)
    norm = norm_rows(s)
    bad = norm < 1e-12
    if np.any(bad):
        if fallback is not None:
            s[bad] = fallback[bad]
        else:
            alt = np.cross(k[bad], np.array([1.0, 0.0, 0.0]))
            s[bad] = alt
        norm = norm_rows(s)
    return s / norm[:, None]


def _cross(a, b):
    """Row-wise cross product (faster than np.cross on (n, 3) arrays; complex allowed)."""
    return np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                     a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=-1)


def inside_fields(k, s, eps):
    """For unit plane waves travelling along ``k`` (n, 3), k_z < 0, with basis (s, p = k x s), ``s``
    (n, 3) normal to k and to z (any unit vector normal to k along the normal): the fields just
    inside the substrate (z < 0) of the s wave and of the p wave, (n, 3) complex each."""
    n = np.sqrt(complex(eps))
    cos = -k[:, 2]
    k_tan = k.copy()
    k_tan[:, 2] = 0.0
    sin2 = k_tan[:, 0] ** 2 + k_tan[:, 1] ** 2
    q = np.sqrt(eps - sin2 + 0j)
    t_s = 2.0 * cos / (cos + q)
    t_p = 2.0 * n * cos / (eps * cos + q)
    k_t = k_tan / n - (q / n)[:, None] * Z
    return t_s[:, None] * s, t_p[:, None] * _cross(k_t, s)


def inside_field(k, e, eps):
    """Field (n, 3) complex just inside the substrate for unit waves along ``k`` with polarization
    vectors ``e`` (n, 3; real, normal to k)."""
    s = s_basis(k, fallback=_unit(e))
    E_s, E_p = inside_fields(k, s, eps)
    p = np.cross(k, s)
    return np.einsum("ij,ij->i", e, s)[:, None] * E_s + np.einsum("ij,ij->i", e, p)[:, None] * E_p


def rayleigh_rice_jones(wi, wo, n, s_in=None, e1_out=None):
    """Jones matrices (m, 2, 2) of first-order scatter from ``wi`` into ``wo`` (sample frame, z the
    normal, both z > 0; wi toward the source), substrate index ``n`` (complex allowed).

    Bases: incident (s_in, p_in = k_i x s_in), k_i = -wi, s_in = k_i x z normalised unless given;
    scattered (e1 = wo x z normalised, or s_in along the normal, unless given; e2 = wo x e1), so
    that specular scatter keeps e1 = s as a mirror does. Returns ``(J, e1_out)``.
    """
    wi = np.asarray(wi, float)
    wo = np.asarray(wo, float)
    eps = complex(n) ** 2
    k_i = -wi
    s_i = s_basis(k_i) if s_in is None else np.asarray(s_in, float)
    e1 = s_basis(wo, fallback=s_i) if e1_out is None else np.asarray(e1_out, float)
    e2 = _cross(wo, e1)
    k_r = -wo
    s_r = s_basis(k_r, fallback=e1)
    p_r = _cross(k_r, s_r)
    E_a = inside_fields(k_i, s_i, eps)  # incident s, p
    F_s, F_p = inside_fields(k_r, s_r, eps)  # reciprocal wave, its own s, p
    E_b = []
    for b in (e1, e2):
        E_b.append((b * s_r).sum(axis=1)[:, None] * F_s + (b * p_r).sum(axis=1)[:, None] * F_p)
    above = (wi[:, 2] > 0) & (wo[:, 2] > 0)  # zero below either horizon (the BRDF is 0 there)
    scale = np.where(above, (eps - 1.0) / (4.0 * np.where(above, wi[:, 2] * wo[:, 2], 1.0)), 0.0)
    J = np.empty((len(wi), 2, 2), complex)
    for b in range(2):
        for a in range(2):
            x = E_a[a] * E_b[b]
            J[:, b, a] = scale * (x[:, 0] + x[:, 1] + eps * x[:, 2])
    return J, e1


def rayleigh_rice_mueller(wi, wo, n, s_in=None, e1_out=None, first_row_only: bool = False):
    """Normalised Mueller matrices (m, 4, 4) (M00 = 1 where defined) and the scattered e1 (m, 3);
    ``first_row_only``: row 0 alone, rows 1-3 zero (:func:`materials.mueller.jones_to_mueller`)."""
    J, e1 = rayleigh_rice_jones(wi, wo, n, s_in, e1_out)
    M = jones_to_mueller(J, first_row_only)
    m00 = M[:, 0, 0]
    if first_row_only:
        M[:, 0, :] = M[:, 0, :] / np.where(m00 > 0, m00, 1.0)[:, None]
        return M, e1
    return M / np.where(m00 > 0, m00, 1.0)[:, None, None], e1
