"""Stokes vectors and Mueller matrices at smooth interfaces (plain numpy, batch axis first).

Convention: a ray's Stokes vector ``S = (S0, S1, S2, S3)`` is given in a reference frame
``(e1, e2 = d x e1)`` carried with the ray (``d`` its direction, ``e1`` a unit vector normal
to it): with complex field components ``E1, E2``, ``S0 = |E1|^2 + |E2|^2``,
``S1 = |E1|^2 - |E2|^2``, ``S2 = 2 Re(E1 E2*)``, ``S3 = 2 Im(E1* E2)``. At an interface the
frame is first rotated onto ``e1 = s`` (the unit vector along d x normal), so that
``S1 = I_s - I_p``; the Fresnel coefficients of :func:`materials.fresnel.fresnel_amplitudes`
act in that basis, and the outgoing ray's frame is again ``e1 = s``.

References
----------
R. A. Chipman, W. S. T. Lam, G. Young, *Polarized Light and Optical Systems* (CRC, 2018),
ch. 6 (Mueller matrices of Fresnel interfaces) and ch. 10 (polarization ray tracing).
Born & Wolf, *Principles of Optics*, §1.4.2 (Stokes parameters), §1.5 (Fresnel).
"""
from __future__ import annotations

import math

import numpy as np

from materials.sampling import lazy_njit


def interface_mueller(a_s, a_p) -> np.ndarray:
    """Mueller matrices (n, 4, 4) of a diagonal Jones matrix ``diag(a_s, a_p)`` in the s/p basis.

    ``M = [[A, B, 0, 0], [B, A, 0, 0], [0, 0, C, D], [0, 0, -D, C]]`` with
    ``A = (|a_s|^2 + |a_p|^2) / 2``, ``B = (|a_s|^2 - |a_p|^2) / 2``, ``C + iD = a_s a_p*``
    (Chipman et al. ch. 6; reflection: ``a = r``; transmission: ``a = t sqrt(Re q / cos_i)``
    so that ``M[0, 0]`` is the power transmittance).
    """
    a_s = np.atleast_1d(np.asarray(a_s, complex))
    a_p = np.atleast_1d(np.asarray(a_p, complex))
    a_s, a_p = np.broadcast_arrays(a_s, a_p)
    ss = np.abs(a_s) ** 2
    pp = np.abs(a_p) ** 2
    c = a_s * np.conj(a_p)
    m = np.zeros(a_s.shape + (4, 4))
    m[..., 0, 0] = m[..., 1, 1] = 0.5 * (ss + pp)
    m[..., 0, 1] = m[..., 1, 0] = 0.5 * (ss - pp)
    m[..., 2, 2] = m[..., 3, 3] = c.real
    m[..., 2, 3] = c.imag
    m[..., 3, 2] = -c.imag
    return m


def apply_interface_mueller(a_s, a_p, stokes, transpose: bool = False) -> np.ndarray:
    """``M S`` (n, 4) for the Mueller matrices M of :func:`interface_mueller` (``M^T S`` with
    ``transpose``: a covector carried backward) and Stokes vectors ``stokes`` (n, 4), without forming
    M: ``(A S0 + B S1, B S0 + A S1, C S2 + D S3, C S3 - D S2)`` (transposed: ``D -> -D``). ``|a|^2``
    and ``a_s a_p*`` are numpy's (its complex kernels' bits, whatever the CPU), the rest one compiled
    pass in :func:`apply_interface_mueller_numpy`'s order: the same bits."""
    s = np.ascontiguousarray(stokes, dtype=float)
    out = np.empty((len(s), 4))
    if len(s):
        a_s, a_p = (a if isinstance(a, np.ndarray) and a.shape == (len(s),) and a.dtype == np.complex128
                    else np.broadcast_to(np.asarray(a, dtype=complex), (len(s),)) for a in (a_s, a_p))
        lazy_njit(_apply_interface_loop, "numpy")(np.abs(a_s) ** 2, np.abs(a_p) ** 2, a_s * np.conj(a_p), s,
                                                  bool(transpose), out)
    return out


def _apply_interface_loop(ss, pp, c, s, transpose, out):
    """:func:`apply_interface_mueller` row by row: einsum's sum over all four products of a row, in
    order from +0 (zeros included: the same bits, signed zeros too)."""
    for r in range(len(s)):
        A = 0.5 * (ss[r] + pp[r])
        B = 0.5 * (ss[r] - pp[r])
        C = c[r].real
        D = c[r].imag
        D23, D32 = (-D, D) if transpose else (D, -D)  # M[2, 3], M[3, 2]
        s0, s1, s2, s3 = s[r, 0], s[r, 1], s[r, 2], s[r, 3]
        out[r, 0] = (((0.0 + A * s0) + B * s1) + 0.0 * s2) + 0.0 * s3
        out[r, 1] = (((0.0 + B * s0) + A * s1) + 0.0 * s2) + 0.0 * s3
        out[r, 2] = (((0.0 + 0.0 * s0) + 0.0 * s1) + C * s2) + D23 * s3
        out[r, 3] = (((0.0 + 0.0 * s0) + 0.0 * s1) + D32 * s2) + C * s3


def apply_interface_mueller_numpy(a_s, a_p, stokes, transpose: bool = False) -> np.ndarray:
    """:func:`apply_interface_mueller` as numpy evaluates it (the reference it is tested against)."""
    return np.einsum("nji,nj->ni" if transpose else "nij,nj->ni", interface_mueller(a_s, a_p), stokes)


def rotation_mueller(cos_psi, sin_psi) -> np.ndarray:
    """Mueller matrices (n, 4, 4) that re-express S in a frame turned by psi about the ray.

    New ``e1' = cos psi e1 + sin psi e2``: ``S1' = cos 2psi S1 + sin 2psi S2``,
    ``S2' = -sin 2psi S1 + cos 2psi S2`` (S0, S3 unchanged).
    """
    c = np.atleast_1d(np.asarray(cos_psi, float))
    s = np.atleast_1d(np.asarray(sin_psi, float))
    c2 = c * c - s * s
    s2 = 2.0 * c * s
    m = np.zeros(c.shape + (4, 4))
    m[..., 0, 0] = m[..., 3, 3] = 1.0
    m[..., 1, 1] = m[..., 2, 2] = c2
    m[..., 1, 2] = s2
    m[..., 2, 1] = -s2
    return m


def rotate_stokes(stokes, e1_from, e1_to, direction) -> np.ndarray:
    """Stokes vectors (n, 4) re-expressed from the frame ``e1_from`` to ``e1_to`` (both normal to
    ``direction``, all (n, 3) unit vectors): ``cos psi = e1_from . e1_to``,
    ``sin psi = (direction x e1_from) . e1_to``. One compiled pass, :func:`rotate_stokes_numpy`'s
    operations in its order (the same bits)."""
    s = np.ascontiguousarray(stokes, dtype=float)
    out = s.copy()
    if len(s):
        lazy_njit(_rotate_stokes_loop, "numpy")(s, np.ascontiguousarray(e1_from, dtype=float),
                                                np.ascontiguousarray(e1_to, dtype=float),
                                                np.ascontiguousarray(direction, dtype=float), out)
    return out


def _rotate_stokes_loop(s, a, b, d, out):
    """:func:`rotate_stokes_numpy` row by row (einsum's dot order ``(x0 y0 + x2 y2) + x1 y1``)."""
    for r in range(len(s)):
        a0, a1, a2 = a[r, 0], a[r, 1], a[r, 2]
        b0, b1, b2 = b[r, 0], b[r, 1], b[r, 2]
        d0, d1, d2 = d[r, 0], d[r, 1], d[r, 2]
        cos_psi = (a0 * b0 + a2 * b2) + a1 * b1
        c0, c1, c2 = d1 * a2 - d2 * a1, d2 * a0 - d0 * a2, d0 * a1 - d1 * a0
        sin_psi = (c0 * b0 + c2 * b2) + c1 * b1
        cc = cos_psi * cos_psi - sin_psi * sin_psi
        ss = 2.0 * cos_psi * sin_psi
        s1, s2 = s[r, 1], s[r, 2]
        out[r, 1] = cc * s1 + ss * s2
        out[r, 2] = -ss * s1 + cc * s2


def rotate_stokes_numpy(stokes, e1_from, e1_to, direction) -> np.ndarray:
    """:func:`rotate_stokes` in vectorised numpy (the reference it is tested against)."""
    d = np.asarray(direction, float)
    a = np.asarray(e1_from, float)
    b = np.asarray(e1_to, float)
    cos_psi = np.einsum("ij,ij->i", a, b)
    sin_psi = np.einsum("ij,ij->i", np.cross(d, a), b)
    s = np.asarray(stokes, float)
    c2 = cos_psi * cos_psi - sin_psi * sin_psi
    s2 = 2.0 * cos_psi * sin_psi
    out = s.copy()
    out[:, 1] = c2 * s[:, 1] + s2 * s[:, 2]
    out[:, 2] = -s2 * s[:, 1] + c2 * s[:, 2]
    return out


def cross_rows(a, b) -> np.ndarray:
    """Row-wise a x b of (n, 3) arrays: ``np.cross``'s products and differences, in its order (the
    same bits), without its axis handling."""
    return np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                     a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=-1)


def norm_rows(v) -> np.ndarray:
    """Row-wise |v| of an (n, 3) array in ``np.linalg.norm(v, axis=1)``'s order (the same bits)."""
    return np.sqrt((v[:, 0] * v[:, 0] + v[:, 1] * v[:, 1]) + v[:, 2] * v[:, 2])


def s_vector(direction, normal) -> np.ndarray:
    """The s unit vector (n, 3) of rays ``direction`` hitting a surface of ``normal``:
    ``d x n`` normalised; at normal incidence any unit vector normal to ``d`` (a fixed rule:
    ``d x x`` or, when that vanishes, ``d x y``). One compiled pass, :func:`s_vector_numpy`'s
    operations in its order (the same bits)."""
    d = np.ascontiguousarray(direction, dtype=float)
    n = np.ascontiguousarray(normal, dtype=float)
    out = np.empty((len(d), 3))
    if len(d):
        lazy_njit(_s_vector_loop, "numpy")(d, n, out)
    return out


def _s_vector_loop(d, n, out):
    """:func:`s_vector_numpy` row by row: np.cross's products with the unit vectors written out."""
    for r in range(len(d)):
        d0, d1, d2 = d[r, 0], d[r, 1], d[r, 2]
        n0, n1, n2 = n[r, 0], n[r, 1], n[r, 2]
        s0, s1, s2 = d1 * n2 - d2 * n1, d2 * n0 - d0 * n2, d0 * n1 - d1 * n0
        norm = math.sqrt((s0 * s0 + s1 * s1) + s2 * s2)
        if norm < 1e-12:  # d x (1, 0, 0), or d x (0, 1, 0) when that vanishes too
            s0, s1, s2 = d1 * 0.0 - d2 * 0.0, d2 * 1.0 - d0 * 0.0, d0 * 0.0 - d1 * 1.0
            norm = math.sqrt((s0 * s0 + s1 * s1) + s2 * s2)
            if norm < 1e-6:
                s0, s1, s2 = d1 * 0.0 - d2 * 1.0, d2 * 0.0 - d0 * 0.0, d0 * 1.0 - d1 * 0.0
                norm = math.sqrt((s0 * s0 + s1 * s1) + s2 * s2)
        out[r, 0], out[r, 1], out[r, 2] = s0 / norm, s1 / norm, s2 / norm


def s_vector_numpy(direction, normal) -> np.ndarray:
    """:func:`s_vector` in vectorised numpy (the reference it is tested against)."""
    d = np.asarray(direction, float)
    n = np.asarray(normal, float)
    s = np.cross(d, n)
    norm = np.linalg.norm(s, axis=1)
    bad = norm < 1e-12
    if np.any(bad):
        alt = np.cross(d[bad], np.array([1.0, 0.0, 0.0]))
        small = np.linalg.norm(alt, axis=1) < 1e-6
        alt[small] = np.cross(d[bad][small], np.array([0.0, 1.0, 0.0]))
        s[bad] = alt
        norm[bad] = np.linalg.norm(alt, axis=1)
    return s / norm[:, None]


def linear_stokes(e_field, direction, e1) -> np.ndarray:
    """Stokes vectors (n, 4) of unit-power linear polarization along ``e_field`` (n, 3), in the
    frame ``e1`` of rays ``direction``: ``(1, cos 2a, sin 2a, 0)`` with ``a`` the angle of the
    field from e1 toward e2 = d x e1."""
    d = np.asarray(direction, float)
    e = np.asarray(e_field, float)
    e1 = np.asarray(e1, float)
    c = np.einsum("ij,ij->i", e, e1)
    s = np.einsum("ij,ij->i", e, np.cross(d, e1))
    norm = np.hypot(c, s)
    norm = np.where(norm > 0, norm, 1.0)
    c, s = c / norm, s / norm
    return np.stack([np.ones_like(c), c * c - s * s, 2 * c * s, np.zeros_like(c)], axis=1)


def polarized_value(value_s, value_p, stokes) -> np.ndarray:
    """A quantity that is ``value_s`` for s and ``value_p`` for p light (no analyser), for light of
    Stokes vector (n, 4) given in the s/p frame: ``S0 [(v_s + v_p)/2 + (S1/S0)(v_s - v_p)/2]``
    per unit S0 (i.e. returns the factor for unit power)."""
    s = np.asarray(stokes, float)
    s0 = np.where(s[:, 0] > 0, s[:, 0], 1.0)
    dop1 = s[:, 1] / s0
    return 0.5 * (value_s + value_p) + 0.5 * dop1 * (value_s - value_p)


# Pauli matrices in the order of the Stokes parameters (S_i = tr(sigma_i C), C = E E^dagger):
# S0 = |E1|^2 + |E2|^2, S1 = |E1|^2 - |E2|^2, S2 = 2 Re(E1 E2*), S3 = 2 Im(E1* E2).
PAULI = np.array([[[1, 0], [0, 1]], [[1, 0], [0, -1]], [[0, 1], [1, 0]], [[0, -1j], [1j, 0]]], complex)


def jones_to_mueller(J, first_row_only: bool = False) -> np.ndarray:
    """Mueller matrices (n, 4, 4) of Jones matrices J (n, 2, 2) (``E_out = J E_in``, components
    along (e1, e2) of each side): ``M_ij = tr(sigma_i J sigma_j J^dagger) / 2`` (Chipman et al.
    ch. 6, with this module's Stokes convention; for a diagonal J it is :func:`interface_mueller`).
    ``first_row_only``: rows 1-3 are left zero (the scattered power ``M[0] . S`` needs only row 0:
    ``M_0j = Re(K_j,00 + K_j,11) / 2``, the same products as the full matrix's row 0)."""
    J = np.asarray(J, complex)
    a, b, c, d = J[..., 0, 0], J[..., 0, 1], J[..., 1, 0], J[..., 1, 1]
    ca, cb, cc, cd = np.conj(a), np.conj(b), np.conj(c), np.conj(d)
    if first_row_only:
        K00_11 = [(a * ca + b * cb, c * cc + d * cd), (a * ca - b * cb, c * cc - d * cd),
                  (b * ca + a * cb, d * cc + c * cd), (1j * (b * ca - a * cb), 1j * (d * cc - c * cd))]
        M = np.zeros(J.shape[:-2] + (4, 4))
        for j, (k00, k11) in enumerate(K00_11):
            M[..., 0, j] = 0.5 * (k00 + k11).real
        return M
    # K_j = J sigma_j J^dagger, element by element (00, 11, 01, 10)
    K = [(a * ca + b * cb, c * cc + d * cd, a * cc + b * cd, c * ca + d * cb),
         (a * ca - b * cb, c * cc - d * cd, a * cc - b * cd, c * ca - d * cb),
         (b * ca + a * cb, d * cc + c * cd, b * cc + a * cd, d * ca + c * cb),
         (1j * (b * ca - a * cb), 1j * (d * cc - c * cd), 1j * (b * cc - a * cd), 1j * (d * ca - c * cb))]
    M = np.empty(J.shape[:-2] + (4, 4))
    for j, (k00, k11, k01, k10) in enumerate(K):  # M_ij = tr(sigma_i K_j) / 2
        M[..., 0, j] = 0.5 * (k00 + k11).real
        M[..., 1, j] = 0.5 * (k00 - k11).real
        M[..., 2, j] = 0.5 * (k01 + k10).real
        M[..., 3, j] = 0.5 * (1j * (k01 - k10)).real
    return M
