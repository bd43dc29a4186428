"""Fresnel reflectance and the Rayleigh-Rice polarization factors Q.

Substrate index ``n`` is real or complex (``n + i k``), eps = n^2, and
``q = sqrt(eps - sin^2 theta)`` on the principal branch (Im q >= 0 for an absorbing
substrate). The incident beam's polarization is s, p or u (the mean of s and p);
the detector has no analyser (CONTRACTS §1).

References
----------
Born & Wolf, *Principles of Optics*, §1.5 (Fresnel equations).
T. A. Germer, "Angular dependence and polarization of out-of-plane optical
scattering from particulate contamination, subsurface defects, and surface
microroughness", Appl. Opt. 36, 8798 (1997); NIST SCATMECH ``urough.cpp``
(first-order vector perturbation; formulas in PHYSICS §1).
"""
from __future__ import annotations

import math

import numpy as np

from materials.base import MaterialError, check_polarization
from materials.sampling import lazy_njit


def complex_index(n) -> complex:
    """``n`` as given in a material file (a number, or ``[n, k]``) -> complex n + i k."""
    if isinstance(n, (list, tuple)):
        if len(n) != 2:
            raise MaterialError(f"refractive index must be a number or [n, k], got {n!r}")
        return complex(float(n[0]), float(n[1]))
    return complex(float(n), 0.0)


def _q(eps, sin2):
    return np.sqrt(eps - sin2 + 0j)


def fresnel_reflectance(theta, n, polarization: str = "u") -> np.ndarray:
    """Power reflectance R_s, R_p or (R_s + R_p) / 2 at incidence ``theta`` (radians).

    ``r_s = (cos - q) / (cos + q)``, ``r_p = (eps cos - q) / (eps cos + q)``.
    """
    check_polarization(polarization)
    n = complex(n) if not isinstance(n, (list, tuple)) else complex_index(n)
    eps = n * n
    c = np.cos(np.asarray(theta, float))
    q = _q(eps, 1.0 - c * c)
    rs = np.abs((c - q) / (c + q)) ** 2
    rp = np.abs((eps * c - q) / (eps * c + q)) ** 2
    return {"s": rs, "p": rp, "u": 0.5 * (rs + rp)}[polarization]


def polarization_factor(cos_i, cos_r, cos_phi, sin_phi, n, polarization: str = "u") -> np.ndarray:
    """Rayleigh-Rice polarization factor Q for an incident polarization, no analyser.

    Germer (1997), PHYSICS §1, with phi_r measured from the specular half-plane::

        ss = (eps-1) cos(phi) / ((cos_i + q_i)(cos_r + q_r))
        ps = (eps-1) q_r sin(phi) / ((cos_i + q_i)(eps cos_r + q_r))
        sp = (eps-1) q_i sin(phi) / ((eps cos_i + q_i)(cos_r + q_r))
        pp = (eps-1)(q_i q_r cos(phi) - eps sin_i sin_r) / ((eps cos_i + q_i)(eps cos_r + q_r))

    s: ``|ss|^2 + |ps|^2``; p: ``|pp|^2 + |sp|^2``; u: their mean.
    At the specular direction Q_s = R_s and Q_p = R_p.

    Parameters
    ----------
    cos_i, cos_r, cos_phi, sin_phi : (n,) float64
    n : complex refractive index of the substrate
    """
    check_polarization(polarization)
    eps = complex(n) ** 2
    cos_i = np.asarray(cos_i, float)
    cos_r = np.asarray(cos_r, float)
    if eps.imag == 0.0 and eps.real >= 1.0:
        # real index >= 1: every factor is real; one compiled pass (the same operations in the same
        # order as the complex branch below on real numbers, so the same bits as numpy's)
        shape = np.broadcast(cos_i, cos_r, cos_phi, sin_phi).shape
        args = [_flat_float(a, shape) for a in (cos_i, cos_r, cos_phi, sin_phi)]
        which = {"s": 0, "p": 1, "u": 2}[polarization]
        return lazy_njit(_real_polarization_factor, "numpy")(*args, eps.real, which).reshape(shape)
    sin2_i = np.maximum(0.0, 1.0 - cos_i * cos_i)
    sin2_r = np.maximum(0.0, 1.0 - cos_r * cos_r)
    qi = _q(eps, sin2_i)
    qr = _q(eps, sin2_r)

    def _abs2(z):
        return z.real**2 + z.imag**2

    e1 = eps - 1.0
    di_s = cos_i + qi
    di_p = eps * cos_i + qi
    dr_s = cos_r + qr
    dr_p = eps * cos_r + qr
    out = 0.0
    if polarization in ("s", "u"):
        ss = e1 * cos_phi / (di_s * dr_s)
        ps = e1 * qr * sin_phi / (di_s * dr_p)
        qs = _abs2(ss) + _abs2(ps)
        if polarization == "s":
            return qs
        out = 0.5 * qs
    sp = e1 * qi * sin_phi / (di_p * dr_s)
    pp = e1 * (qi * qr * cos_phi - eps * np.sqrt(sin2_i * sin2_r)) / (di_p * dr_p)
    qp = _abs2(pp) + _abs2(sp)
    if polarization == "p":
        return qp
    return out + 0.5 * qp


def _real_polarization_factor(cos_i, cos_r, cos_phi, sin_phi, eps, which):
    """:func:`polarization_factor` for a real eps >= 1, element by element (which: 0 s, 1 p, 2 u)."""
    n = len(cos_i)
    out = np.empty(n)
    e1 = eps - 1.0
    for k in range(n):
        ci, cr = cos_i[k], cos_r[k]
        sin2_i = 1.0 - ci * ci
        sin2_i = sin2_i if (sin2_i > 0.0 or sin2_i != sin2_i) else 0.0  # np.maximum(0, .): NaN kept
        sin2_r = 1.0 - cr * cr
        sin2_r = sin2_r if (sin2_r > 0.0 or sin2_r != sin2_r) else 0.0
        qi = math.sqrt(eps - sin2_i)
        qr = math.sqrt(eps - sin2_r)
        di_s = ci + qi
        di_p = eps * ci + qi
        dr_s = cr + qr
        dr_p = eps * cr + qr
        qs = 0.0
        if which != 1:
            ss = e1 * cos_phi[k] / (di_s * dr_s)
            ps = e1 * qr * sin_phi[k] / (di_s * dr_p)
            qs = ss * ss + ps * ps
            if which == 0:
                out[k] = qs
                continue
        sp = e1 * qi * sin_phi[k] / (di_p * dr_s)
        pp = e1 * (qi * qr * cos_phi[k] - eps * math.sqrt(sin2_i * sin2_r)) / (di_p * dr_p)
        qp = pp * pp + sp * sp
        out[k] = qp if which == 1 else 0.5 * qs + 0.5 * qp
    return out


def _flat_float(a, shape) -> np.ndarray:
    """``a`` broadcast to ``shape``, contiguous float64, flattened (itself, viewed, when it is already
    that: np.broadcast_to is slow on the walk's small arrays)."""
    if isinstance(a, np.ndarray) and a.shape == shape and a.dtype == np.float64 and a.flags.c_contiguous:
        return a.reshape(-1)
    return np.ascontiguousarray(np.broadcast_to(np.asarray(a, float), shape)).ravel()


def scatter_azimuth(wi, wo) -> tuple[np.ndarray, np.ndarray]:
    """cos(phi_r), sin(phi_r) of wo about the specular half-plane of wi, (n,) each.

    phi_r = 0 is the specular half-plane (CONTRACTS §1). At normal incidence the
    plane of incidence is taken as xz (phi_i = pi); at theta_r = 0, phi_r = 0.
    """
    # contiguous and writable: one compiled loop (numba types a read-only array apart: a kernel more to load)
    wi = np.require(wi, dtype=float, requirements=("C", "W"))
    wo = np.require(wo, dtype=float, requirements=("C", "W"))
    return lazy_njit(_scatter_azimuth_loop)(wi.reshape(-1, 3), wo.reshape(-1, 3))


def _scatter_azimuth_loop(wi, wo):
    """:func:`scatter_azimuth`, one ray at a time: with t = -(wi_x, wi_y), o = (wo_x, wo_y),
    cos = (o . t) / (|t| |o|), sin = (t x o) / (|t| |o|); |t| |o| <= 1e-30: o / |o| (normal
    incidence, plane of incidence xz), or (1, 0) when |o| <= 1e-15 too."""
    n = wi.shape[0]
    cos_phi = np.empty(n)
    sin_phi = np.empty(n)
    for k in range(n):
        tx, ty = -wi[k, 0], -wi[k, 1]
        ox, oy = wo[k, 0], wo[k, 1]
        on = math.hypot(ox, oy)
        norm = math.hypot(tx, ty) * on
        if norm > 1e-30:
            inv = 1.0 / norm
            cos_phi[k] = (ox * tx + oy * ty) * inv
            sin_phi[k] = (tx * oy - ty * ox) * inv
        elif on > 1e-15:
            cos_phi[k] = ox / on
            sin_phi[k] = oy / on
        else:
            cos_phi[k] = 1.0
            sin_phi[k] = 0.0
    return cos_phi, sin_phi


def fresnel_amplitudes(cos_i, m):
    """Amplitude coefficients of a plane interface, incidence from medium 1 into medium 2.

    ``m = n2 / n1`` (real or complex, scalar or (n,)), ``cos_i`` (n,) the cosine of the
    incidence angle in medium 1 (>= 0). With ``q = sqrt(m^2 - sin^2 theta_i) = m cos theta_t``
    (principal branch, Im q >= 0; imaginary under total internal reflection)::

        r_s = (cos_i - q) / (cos_i + q)            r_p = (m^2 cos_i - q) / (m^2 cos_i + q)
        t_s = 2 cos_i / (cos_i + q)                t_p = 2 m cos_i / (m^2 cos_i + q)

    Basis: s = the unit vector along (propagation x normal), p = propagation x s, on both sides
    of the interface (so r_p = -r_s at normal incidence and a perfect conductor has r_s = -1,
    r_p = +1; Born & Wolf §1.5 with the p vectors turned accordingly; the same r_p as
    :func:`fresnel_reflectance`).

    Returns
    -------
    r_s, r_p, t_s, t_p : (n,) complex128
    q : (n,) complex128, m cos(theta_t)
    """
    c = np.asarray(cos_i, float)
    m = np.asarray(m, complex)
    if m.ndim or c.ndim != 1:
        return fresnel_amplitudes_numpy(c, m)
    m2 = m * m  # numpy's products of the scalar (its bits), the rows in one compiled pass
    out = np.empty((5, len(c)), complex)
    if len(c):
        lazy_njit(_fresnel_amplitudes_loop, "numpy")(np.ascontiguousarray(c), complex(m2), complex(2.0 * m), out)
    return out[0], out[1], out[2], out[3], out[4]


def _fresnel_amplitudes_loop(c, m2, two_m, out):
    """:func:`fresnel_amplitudes_numpy` row by row, for a scalar m: real times complex as numpy casts it
    (``(x + 0j) z``; one product is then exact zero, so numpy's fused multiply-add changes nothing),
    complex quotients as numpy forms them (Smith's rule with a reciprocal)."""

    def cdiv(a, b):  # also in materials/rayleigh_rice.py's kernel: numba's cache does not see a change in a jitted callee
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

    for r in range(len(c)):
        x = c[r]
        cz = complex(x, 0.0)
        q = np.sqrt((m2 - (1.0 - x * x)) + 0j)
        ds = cz + q
        m2c = m2 * cz
        dp = m2c + q
        out[0, r] = cdiv(cz - q, ds)
        out[1, r] = cdiv(m2c - q, dp)
        out[2, r] = cdiv(complex(2.0 * x, 0.0), ds)
        out[3, r] = cdiv(two_m * cz, dp)
        out[4, r] = q


def fresnel_amplitudes_numpy(cos_i, m):
    """:func:`fresnel_amplitudes` in vectorised numpy (the reference it is tested against)."""
    c = np.asarray(cos_i, float)
    m = np.asarray(m, complex)
    m2 = m * m
    q = np.sqrt(m2 - (1.0 - c * c) + 0j)
    ds = c + q
    dp = m2 * c + q
    return (c - q) / ds, (m2 * c - q) / dp, 2.0 * c / ds, 2.0 * m * c / dp, q


def fresnel_power(cos_i, m):
    """Power reflectances and transmittances ``R_s, R_p, T_s, T_p`` (n,) of a plane interface.

    ``R = |r|^2``; for a real ``m``, ``T = Re(q) / cos_i |t|^2`` (Born & Wolf §1.5.3), which
    is 0 under total internal reflection and equals ``1 - R``. For a complex ``m`` (an
    absorbing medium 2) the power that enters is taken as ``T = 1 - R``.
    """
    c = np.asarray(cos_i, float)
    rs, rp, ts, tp, q = fresnel_amplitudes(c, m)
    Rs = np.abs(rs) ** 2
    Rp = np.abs(rp) ** 2
    if np.all(np.imag(m) == 0):
        with np.errstate(divide="ignore", invalid="ignore"):
            f = np.where(c > 0, q.real / np.where(c > 0, c, 1.0), 0.0)
        Ts = f * np.abs(ts) ** 2
        Tp = f * np.abs(tp) ** 2
    else:
        Ts = 1.0 - Rs
        Tp = 1.0 - Rp
    return Rs, Rp, Ts, Tp
