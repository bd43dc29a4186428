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

import math

import numpy as np

from materials.mueller import jones_to_mueller, norm_rows
from materials.sampling import lazy_njit

Z = np.array([0.0, 0.0, 1.0])


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def s_basis(k, fallback=None) -> np.ndarray:
    """s = k x z normalised for propagation directions k (n, 3) in the sample frame; along the
    normal, ``fallback`` (n, 3) (unit, normal to k) or the x-based rule of materials.mueller.s_vector.
    One compiled pass (:func:`_s_basis_loop`), :func:`s_basis_numpy`'s operations in its order (the same bits)."""
    k = np.ascontiguousarray(k, dtype=np.float64)
    if k.ndim != 2 or k.shape[1] != 3:
        return s_basis_numpy(k, fallback)
    fb = np.ascontiguousarray(fallback if fallback is not None else np.zeros((0, 3)), dtype=np.float64)
    if fallback is not None and fb.shape != k.shape:
        return s_basis_numpy(k, fallback)
    out = np.empty((len(k), 3))
    if len(k):
        lazy_njit(_s_basis_loop, "numpy")(k, fb, fallback is not None, out)
    return out


def _s_basis_loop(k, fallback, has_fallback, out):
    """:func:`s_basis_numpy` row by row: ``np.cross(k, z)``'s products and differences, ``norm_rows``'
    order ``(x^2 + y^2) + z^2``, the fallback (or ``np.cross(k, x)``) where the norm is below 1e-12."""
    for i in range(len(k)):
        k0, k1, k2 = k[i, 0], k[i, 1], k[i, 2]
        s0 = k1 * 1.0 - k2 * 0.0
        s1 = k2 * 0.0 - k0 * 1.0
        s2 = k0 * 0.0 - k1 * 0.0
        norm = np.sqrt((s0 * s0 + s1 * s1) + s2 * s2)
        if norm < 1e-12:
            if has_fallback:
                s0, s1, s2 = fallback[i, 0], fallback[i, 1], fallback[i, 2]
            else:
                s0 = k1 * 0.0 - k2 * 0.0
                s1 = k2 * 1.0 - k0 * 0.0
                s2 = k0 * 0.0 - k1 * 1.0
            norm = np.sqrt((s0 * s0 + s1 * s1) + s2 * s2)
        out[i, 0] = s0 / norm
        out[i, 1] = s1 / norm
        out[i, 2] = s2 / norm


def s_basis_numpy(k, fallback=None) -> np.ndarray:
    """:func:`s_basis` in vectorised numpy (the reference it is tested against)."""
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
    ``first_row_only``: row 0 alone, rows 1-3 zero (:func:`materials.mueller.jones_to_mueller`).
    :func:`rayleigh_rice_jones`, :func:`materials.mueller.jones_to_mueller` and the normalisation row
    by row in one compiled pass, numpy's operations in numpy's order (complex quotients as numpy forms
    them): the same bits as :func:`rayleigh_rice_mueller_numpy` for a real index; for a complex one
    within 1e-13 (numpy's vectorised complex product fuses a multiply-add on FMA CPUs, the pass does not)."""
    wi = np.asarray(wi, float)
    wo = np.asarray(wo, float)
    s_i = s_basis(-wi) if s_in is None else np.asarray(s_in, float)
    e1 = s_basis(wo, fallback=s_i) if e1_out is None else np.asarray(e1_out, float)
    M = np.zeros((len(wi), 4, 4))
    add_rayleigh_rice_mueller(M, np.zeros((0, len(wi))), wi, wo, n, s_i, e1, first_row_only)
    return M, e1


def add_rayleigh_rice_mueller(M, F, wi, wo, n, s_in, e1_out, first_row_only: bool = False) -> None:
    """``M += F[0] Mn``, then ``M += F[1] Mn``, ... in place (M (m, 4, 4), F (k, m): the BRDFs of k
    components with this substrate index), Mn the normalised matrix of :func:`rayleigh_rice_mueller`
    for the bases ``s_in``, ``e1_out`` (m, 3), computed once (rows 1-3 untouched with
    ``first_row_only``). The same bits as those numpy updates with Mn from the numpy twin (real
    index). With k = 0, ``M = Mn``."""
    if len(wi):
        eps = complex(n) ** 2
        lazy_njit(_rr_mueller_loop, "numpy")(
            np.ascontiguousarray(wi, dtype=float), np.ascontiguousarray(wo, dtype=float),
            np.ascontiguousarray(s_in, dtype=float), np.ascontiguousarray(e1_out, dtype=float), eps,
            complex(np.sqrt(complex(eps))), bool(first_row_only), np.ascontiguousarray(F, dtype=float), M)


def _rr_mueller_loop(wi, wo, s_i, e1, eps, n_idx, first_row_only, F, M):
    """:func:`add_rayleigh_rice_mueller` row by row: :func:`rayleigh_rice_mueller_numpy`'s operations
    (real times complex as numpy casts it: ``(x + 0j) z``), then the updates of M."""

    # a / b as numpy's complex division forms it (Smith's rule, with a reciprocal); also in materials/fresnel.py's
    # kernel: a closure in each, since numba's cache does not see a change in a jitted callee of another module
    def cdiv(a, b):
        ar, ai, br, bi = a.real, a.imag, b.real, b.imag
        if abs(br) >= abs(bi):
            if br == 0.0 and bi == 0.0:
                return complex(ar / abs(br), ai / abs(br))
            rat = bi / br
            scl = 1.0 / (br + bi * rat)
            return complex((ar + ai * rat) * scl, (ai - ar * rat) * scl)
        rat = br / bi
        scl = 1.0 / (bi + br * rat)
        return complex((ar * rat + ai) * scl, (ai * rat - ar) * scl)

    def inside(k0, k1, k2, s0, s1, s2):  # inside_fields: (E_s, E_p) of the waves along k with basis s
        cos = -k2
        sin2 = k0 * k0 + k1 * k1
        q = np.sqrt((eps - sin2) + 0j)
        t_s = cdiv(complex(2.0 * cos, 0.0), cos + q)
        t_p = cdiv((2.0 * n_idx) * cos, eps * cos + q)
        qn = cdiv(q, n_idx)
        kt0 = cdiv(complex(k0, 0.0), n_idx) - qn * 0.0
        kt1 = cdiv(complex(k1, 0.0), n_idx) - qn * 0.0
        kt2 = cdiv(0j, n_idx) - qn * 1.0
        return (t_s * s0, t_s * s1, t_s * s2, t_p * (kt1 * s2 - kt2 * s1), t_p * (kt2 * s0 - kt0 * s2),
                t_p * (kt0 * s1 - kt1 * s0))

    em1 = eps - 1.0
    mn = np.empty((4, 4))  # the row's normalised matrix
    for r in range(len(wi)):
        wi0, wi1, wi2 = wi[r, 0], wi[r, 1], wi[r, 2]
        wo0, wo1, wo2 = wo[r, 0], wo[r, 1], wo[r, 2]
        a0, a1, a2 = e1[r, 0], e1[r, 1], e1[r, 2]
        si0, si1, si2 = s_i[r, 0], s_i[r, 1], s_i[r, 2]
        b0, b1, b2 = wo1 * a2 - wo2 * a1, wo2 * a0 - wo0 * a2, wo0 * a1 - wo1 * a0  # e2 = wo x e1
        kr0, kr1, kr2 = -wo0, -wo1, -wo2
        t0, t1, t2 = kr1 * 1.0 - kr2 * 0.0, kr2 * 0.0 - kr0 * 1.0, kr0 * 0.0 - kr1 * 0.0  # s_basis(k_r, e1)
        nrm = math.sqrt((t0 * t0 + t1 * t1) + t2 * t2)
        if nrm < 1e-12:
            t0, t1, t2 = a0, a1, a2
            nrm = math.sqrt((t0 * t0 + t1 * t1) + t2 * t2)
        sr0, sr1, sr2 = t0 / nrm, t1 / nrm, t2 / nrm
        pr0, pr1, pr2 = kr1 * sr2 - kr2 * sr1, kr2 * sr0 - kr0 * sr2, kr0 * sr1 - kr1 * sr0
        Eas0, Eas1, Eas2, Eap0, Eap1, Eap2 = inside(-wi0, -wi1, -wi2, si0, si1, si2)  # incident s, p
        Fs0, Fs1, Fs2, Fp0, Fp1, Fp2 = inside(kr0, kr1, kr2, sr0, sr1, sr2)  # reciprocal wave, its s, p
        cs1, cp1 = (a0 * sr0 + a1 * sr1) + a2 * sr2, (a0 * pr0 + a1 * pr1) + a2 * pr2
        cs2, cp2 = (b0 * sr0 + b1 * sr1) + b2 * sr2, (b0 * pr0 + b1 * pr1) + b2 * pr2
        E10, E11, E12 = cs1 * Fs0 + cp1 * Fp0, cs1 * Fs1 + cp1 * Fp1, cs1 * Fs2 + cp1 * Fp2  # E_b, b = e1
        E20, E21, E22 = cs2 * Fs0 + cp2 * Fp0, cs2 * Fs1 + cp2 * Fp1, cs2 * Fs2 + cp2 * Fp2  # b = e2
        if wi2 > 0 and wo2 > 0:
            scale = cdiv(em1, complex(4.0 * (wi2 * wo2), 0.0))
        else:
            scale = 0j
        ja = scale * ((Eas0 * E10 + Eas1 * E11) + eps * (Eas2 * E12))  # J00
        jb = scale * ((Eap0 * E10 + Eap1 * E11) + eps * (Eap2 * E12))  # J01
        jc = scale * ((Eas0 * E20 + Eas1 * E21) + eps * (Eas2 * E22))  # J10
        jd = scale * ((Eap0 * E20 + Eap1 * E21) + eps * (Eap2 * E22))  # J11
        ca, cb, cc, cd = ja.conjugate(), jb.conjugate(), jc.conjugate(), jd.conjugate()
        m00 = (0.5 * ((ja * ca + jb * cb) + (jc * cc + jd * cd))).real
        den = m00 if m00 > 0 else 1.0
        k00 = (ja * ca + jb * cb, ja * ca - jb * cb, jb * ca + ja * cb, 1j * (jb * ca - ja * cb))
        k11 = (jc * cc + jd * cd, jc * cc - jd * cd, jd * cc + jc * cd, 1j * (jd * cc - jc * cd))
        rows = 1 if first_row_only else 4
        for j in range(4):
            mn[0, j] = (0.5 * (k00[j] + k11[j])).real / den
        if not first_row_only:
            k01 = (ja * cc + jb * cd, ja * cc - jb * cd, jb * cc + ja * cd, 1j * (jb * cc - ja * cd))
            k10 = (jc * ca + jd * cb, jc * ca - jd * cb, jd * ca + jc * cb, 1j * (jd * ca - jc * cb))
            for j in range(4):
                mn[1, j] = (0.5 * (k00[j] - k11[j])).real / den
                mn[2, j] = (0.5 * (k01[j] + k10[j])).real / den
                mn[3, j] = (0.5 * (1j * (k01[j] - k10[j]))).real / den
        for i in range(rows):
            for j in range(4):
                if len(F) == 0:
                    M[r, i, j] = mn[i, j]
                for k in range(len(F)):
                    M[r, i, j] = M[r, i, j] + F[k, r] * mn[i, j]


def rayleigh_rice_mueller_numpy(wi, wo, n, s_in=None, e1_out=None, first_row_only: bool = False):
    """:func:`rayleigh_rice_mueller` in vectorised numpy, from :func:`rayleigh_rice_jones` and
    :func:`materials.mueller.jones_to_mueller` (the reference the compiled pass is tested against)."""
    J, e1 = rayleigh_rice_jones(wi, wo, n, s_in, e1_out)
    M = jones_to_mueller(J, first_row_only)
    m00 = M[:, 0, 0]
    if first_row_only:
        M[:, 0, :] = M[:, 0, :] / np.where(m00 > 0, m00, 1.0)[:, None]
        return M, e1
    return M / np.where(m00 > 0, m00, 1.0)[:, None, None], e1
