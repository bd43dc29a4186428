"""Scatter by particles on a surface: Mie theory over an IEST-STD-CC1246E size distribution.

CONTRACTS §5.1 ``particulate``. Model (docs/materials-models.md, "Particulate contamination"):

- **Size distribution** (IEST-STD-CC1246E, the MIL-STD-1246 log-log^2 law):
  ``log10 N(>x) = slope (log10^2 level - log10^2 x)``, N per 0.1 m^2, x the particle size in
  um, for x >= 1 um; the quadrature runs from 1 um up to the size where ``N(>x) = 1e-3`` per
  0.1 m^2 (beyond it the distribution holds no visible area).
- **Particles** are spheres of diameter x and index ``n`` (default 1.5) in air; each scatters
  with its Mie differential cross section (miepython), and particles scatter independently
  (no multiple scatter between particles, no near-field coupling with the surface).
- **Surface under the particles**: a smooth reflector of Fresnel reflectance R (the material's
  own ``specular``/``dielectric`` component, or ``substrate_n`` / ``substrate_r``; black if
  none). Four incoherent paths reach the viewer (Spyak & Wolfe 1992; Dittman 2002):
  particle only; surface then particle; particle then surface; surface, particle, surface,
  weighted 1, R(theta_i), R(theta_r), R(theta_i) R(theta_r), each with the Mie scattering angle
  of its own pair of directions. Interference between the paths averages out over particle
  sizes and heights and is not modelled.

BRDF (1/sr), with ``P(Theta) = sum over sizes of n_A(x) dsigma/dOmega(x, Theta)`` (number per
mm^2 times mm^2/sr)::

    f = c(theta_i) / (cos_i cos_r) * [P(T1) + R_i P(T2) + R_r P(T3) + R_i R_r P(T4)]

``c = a(theta_i) a(theta_r)``, ``a = (1 - exp(-tau)) / tau``, ``tau = sum n_A sigma_ext / cos``,
keeps the intercepted fraction of the beam below 1 at grazing incidence (Beer-Lambert through a
random layer on the way in and out, so f stays reciprocal; c -> 1 for a clean surface). The incident polarization is not used (the Mie intensities are
averaged over s and p) and the scattered light is treated as unpolarized.

References
----------
IEST-STD-CC1246E, *Product Cleanliness Levels - Applications, Requirements, and Determination*
(IEST, 2013), the size law and the percent area coverage relation
``log10 PAC = -7.245 + 0.926 log10^2(level)``: the area integral of the 0.926 law with counts per
ft^2 (MIL-STD-1246's unit, replaced by 0.1 m^2 in revision D), so the model's PAC (counts per
0.1 m^2) is 0.929 of it.
C. F. Bohren, D. R. Huffman, *Absorption and Scattering of Light by Small Particles* (1983).
S. Prahl, miepython (https://github.com/scottprahl/miepython).
P. R. Spyak, W. L. Wolfe, "Scatter from particulate-contaminated mirrors", Opt. Eng. 31,
1746-1784 (1992).
M. G. Dittman, "Contamination scatter functions for stray-light analysis", Proc. SPIE 4774
(2002).
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, replace
from functools import cached_property, lru_cache
from typing import Optional, Union

import numpy as np

from materials.base import MaterialError, Sample, check_polarization
from materials.fresnel import fresnel_amplitudes
from materials.flags import ComponentFlags
from materials.registry import register
from materials.sampling import check_index, check_real, direction_uniforms, set_fields

MIN_SIZE_UM = 1.0            # the standard's distribution starts at 1 um
TAIL_COUNT = 1e-3            # largest size: N(>x) = 1e-3 per 0.1 m^2
UM2_PER_0P1_M2 = 1e11        # 0.1 m^2 in um^2
N_SIZES = 56                 # Gauss-Legendre nodes in log10(size)


def size_density_per_0p1m2(log10_x, level: float, slope: float) -> np.ndarray:
    """-dN/d(log10 x): particles per 0.1 m^2 per decade of size at log10 x (CC1246E law)."""
    u = np.asarray(log10_x, float)
    lg = math.log10(level)
    return 10.0 ** (slope * (lg * lg - u * u)) * 2.0 * slope * u * math.log(10.0)


def cc1246_pac_percent(level) -> np.ndarray:
    """Percent area coverage of the standard's relation ``log10 PAC = -7.245 + 0.926 log10^2 L``
    (IEST-STD-CC1246E; slope 0.926)."""
    lg = np.log10(np.asarray(level, float))
    return 10.0 ** (-7.245 + 0.926 * lg * lg)


def size_range_log10_um(level: float, slope: float) -> tuple:
    """(log10 x_min, log10 x_max): from 1 um to the size where N(>x) = 1e-3 per 0.1 m^2."""
    lg = math.log10(level)
    return 0.0, math.sqrt(lg * lg - math.log10(TAIL_COUNT) / slope)


def _import_miepython():
    # miepython's compiled (numba) kernels are ~25x faster; they are chosen at import time
    os.environ.setdefault("MIEPYTHON_USE_JIT", "1")
    import miepython

    return miepython


def _angle_grid() -> np.ndarray:
    """Scattering angles (rad): 0, then geometric from 1e-5 to 0.05 rad (forward diffraction
    peaks of particles up to a few mm), then uniform to pi."""
    fine = np.geomspace(1e-5, 0.05, 220)
    coarse = np.linspace(0.05, np.pi, 361)[1:]
    return np.concatenate([[0.0], fine, coarse])


def size_nodes(level: float, slope: float):
    """Quadrature of the size distribution: diameters (um) and particles per um^2 of surface
    (Gauss-Legendre in log10 x over :func:`size_range_log10_um`)."""
    u0, u1 = size_range_log10_um(level, slope)
    xg, wg = np.polynomial.legendre.leggauss(N_SIZES)
    u = 0.5 * (u1 - u0) * xg + 0.5 * (u1 + u0)
    w = 0.5 * (u1 - u0) * wg
    return 10.0 ** u, size_density_per_0p1m2(u, level, slope) * w / UM2_PER_0P1_M2


def percent_area_coverage(level: float, slope: float = 0.926) -> float:
    """Percent of the surface covered by the particles' geometric cross sections (pi x^2 / 4)
    for the model's distribution (:func:`size_nodes`)."""
    d_um, count = size_nodes(level, slope)
    return 100.0 * float(np.sum(count * np.pi * d_um * d_um / 4.0))


@lru_cache(maxsize=16)
def mie_table(level: float, slope: float, n_re: float, n_im: float, wavelength_nm: float, sizes=None):
    """Size-integrated Mie tables for one distribution.

    Returns ``(theta (T,), P (T,) 1/sr, sigma_sca, sigma_ext, coverage)``: ``P(Theta)`` is the
    differential scattering cross section per unit surface area (unpolarized), ``sigma_*`` the
    total cross sections per unit area (dimensionless) and ``coverage`` the geometric area
    fraction of the particles (the model's percent area coverage / 100). ``sizes``, if given,
    is a tuple of (diameter_um, particles per um^2) pairs replacing the distribution.
    """
    mp = _import_miepython()
    theta = _angle_grid()
    mu = np.cos(theta)
    if sizes is None:
        d_um, count_per_um2 = size_nodes(level, slope)
    else:
        d_um = np.array([s[0] for s in sizes], float)
        count_per_um2 = np.array([s[1] for s in sizes], float)
    area_um2 = np.pi * d_um * d_um / 4.0
    lam_um = wavelength_nm * 1e-3
    m = complex(n_re, -n_im)  # miepython: m = n - i k
    P = np.zeros_like(theta)
    sca = ext = 0.0
    for nk, a, d in zip(count_per_um2, area_um2, d_um):
        x = np.pi * d / lam_um
        qext, qsca, _, _ = mp.efficiencies_mx(m, x)
        i_u = mp.i_unpolarized(m, x, mu, norm="qsca")  # integrates to qsca over 4 pi
        P += nk * a * i_u
        sca += nk * a * float(qsca)
        ext += nk * a * float(qext)
    coverage = float(np.sum(count_per_um2 * area_um2))
    return theta, P, sca, ext, coverage


@register("particulate")
@dataclass(frozen=True)
class Particulate:
    """Particulate contamination scatter (CONTRACTS §5.1 ``particulate``), see the module doc.

    Parameters
    ----------
    level : float
        IEST-STD-CC1246E cleanliness level (> 1), the size in um with one particle per 0.1 m^2.
    slope : float
        The distribution's slope (default 0.926).
    n : float or [n, k]
        Particle refractive index (default 1.5).
    weight : float
        Multiplies the lobe (default 1).
    substrate_n : float or [n, k], optional
        Index of the smooth surface under the particles; default: the material's ``specular`` or
        ``dielectric`` component (the surface is black when there is none).
    substrate_r : float, optional
        A constant reflectance instead of ``substrate_n``.
    wavelength_nm : float, optional
        Defaults to the material's.
    """

    level: float
    slope: float = 0.926
    n: Union[float, tuple] = 1.5
    weight: float = 1.0
    substrate_n: Optional[Union[float, tuple]] = None
    substrate_r: Optional[float] = None
    wavelength_nm: Optional[float] = None

    flags = ComponentFlags.GLOSSY
    reciprocal = True
    needs_substrate = True

    def __post_init__(self):
        o = "particulate"
        set_fields(
            self,
            level=check_real(o, "level", self.level, lo=1.0, lo_open=True, hi=1e5),
            slope=check_real(o, "slope", self.slope, lo=0.0, lo_open=True),
            weight=check_real(o, "weight", self.weight, lo=0.0),
        )
        n, k = check_index(o, "n", self.n)
        set_fields(self, n=(n, k) if k else n)
        if self.substrate_n is not None and self.substrate_r is not None:
            raise MaterialError(f"{o}: give at most one of 'substrate_n' and 'substrate_r'")
        if self.substrate_n is not None:
            sn, sk = check_index(o, "substrate_n", self.substrate_n)
            set_fields(self, substrate_n=(sn, sk) if sk else sn)
        if self.substrate_r is not None:
            set_fields(self, substrate_r=check_real(o, "substrate_r", self.substrate_r, lo=0.0, hi=1.0))
        if self.wavelength_nm is not None:
            set_fields(self, wavelength_nm=check_real(o, "wavelength_nm", self.wavelength_nm, lo=0.0, lo_open=True))

    @classmethod
    def example(cls) -> "Particulate":
        return cls(level=300, wavelength_nm=532.0, substrate_n=(0.96, 6.69))

    # ------------------------------------------------------------ substrate

    @property
    def substrate_unset(self) -> bool:
        return self.substrate_n is None and self.substrate_r is None

    def with_substrate(self, smooth) -> "Particulate":
        """A copy whose surface under the particles is the delta component ``smooth``."""
        if getattr(smooth, "r", None) is not None:
            return replace(self, substrate_r=smooth.r * getattr(smooth, "weight", 1.0))
        n = getattr(smooth, "n")
        n_out = getattr(smooth, "n_outside", 1.0)
        if isinstance(n, tuple):
            return replace(self, substrate_n=(n[0] / n_out, n[1] / n_out))
        return replace(self, substrate_n=n / n_out)

    def substrate_reflectance(self, cos_theta) -> np.ndarray:
        """Unpolarized reflectance of the surface under the particles at cos(theta) (n,)."""
        c = np.clip(np.asarray(cos_theta, float), 0.0, 1.0)
        if self.substrate_r is not None:
            return np.full(c.shape, self.substrate_r)
        if self.substrate_n is None:
            return np.zeros(c.shape)
        sn = self.substrate_n
        m = complex(*sn) if isinstance(sn, tuple) else complex(sn, 0.0)
        rs, rp, _, _, _ = fresnel_amplitudes(c, m)
        return 0.5 * (np.abs(rs) ** 2 + np.abs(rp) ** 2)

    # ------------------------------------------------------------ tables

    def _need_wavelength(self) -> float:
        if self.wavelength_nm is None:
            raise MaterialError("particulate: needs wavelength_nm (give it in the material or the component)")
        return self.wavelength_nm

    @classmethod
    def single_size(cls, diameter_um: float, particles_per_mm2: float, **kw) -> "Particulate":
        """Particles of one diameter (a test and teaching aid; not a material-file form)."""
        obj = cls(level=2.0, **kw)
        object.__setattr__(obj, "_sizes", ((float(diameter_um), float(particles_per_mm2) * 1e-6),))
        return obj

    @cached_property
    def _table(self):
        n_re, n_im = self.n if isinstance(self.n, tuple) else (self.n, 0.0)
        theta, P, sca, ext, cov = mie_table(float(self.level), float(self.slope), float(n_re), float(n_im),
                                            float(self._need_wavelength()), getattr(self, "_sizes", None))
        mu = np.cos(theta)[::-1]               # increasing mu
        P_mu = P[::-1] * self.weight
        # sampling histogram in mu: mass of each bin from the trapezoid of P over mu
        mass = 0.5 * (P_mu[1:] + P_mu[:-1]) * np.diff(mu) * 2.0 * np.pi
        cdf = np.concatenate([[0.0], np.cumsum(mass)])
        total = cdf[-1]
        density = mass / total / np.diff(mu) / (2.0 * np.pi)   # per sr, constant within a bin
        back = float(np.interp(0.0, mu, cdf / total))
        return {"mu": mu, "P": P_mu, "cdf": cdf / total, "density": density, "back": max(back, 1e-3),
                "sca": sca * self.weight, "ext": ext * self.weight, "coverage": cov}

    @property
    def percent_area_coverage(self) -> float:
        """Geometric area covered by the model's particles, in percent (per 0.1 m^2 of surface,
        the distribution integrated from 1 um to its N(>x) = 1e-3 size)."""
        return 100.0 * self._table["coverage"]

    @property
    def scatter_cross_section(self) -> float:
        """Total Mie scattering cross section of the particles per unit surface area."""
        return self._table["sca"]

    def phase(self, cos_theta) -> np.ndarray:
        """P(Theta): differential scattering cross section per unit area (1/sr), interpolated
        linearly in cos(Theta) on the table."""
        t = self._table
        return np.interp(np.asarray(cos_theta, float), t["mu"], t["P"])

    def _attenuation(self, cos_i) -> np.ndarray:
        tau = self._table["ext"] / np.maximum(cos_i, 1e-12)
        return np.where(tau > 1e-8, -np.expm1(-tau) / np.maximum(tau, 1e-300), 1.0 - 0.5 * tau)

    # ------------------------------------------------------------ protocol

    def _path_cosines(self, wi, wo):
        """cos(Theta) of the four paths: k_in = -wi, k_spec = mirrored k_in, wo' = mirrored wo."""
        kin = -wi
        ksp = kin * np.array([1.0, 1.0, -1.0])
        wom = wo * np.array([1.0, 1.0, -1.0])
        dot = lambda a, b: np.einsum("ij,ij->i", a, b)  # noqa: E731
        return dot(kin, wo), dot(ksp, wo), dot(kin, wom), dot(ksp, wom)

    def brdf(self, wi, wo, polarization: str = "u") -> np.ndarray:
        """BRDF in 1/sr (no cos); see the module docstring. wi, wo : (n, 3), sample frame."""
        check_polarization(polarization)
        wi = np.asarray(wi, float)
        wo = np.asarray(wo, float)
        ci, cr = wi[:, 2], wo[:, 2]
        above = (ci > 0) & (cr > 0)
        c1, c2, c3, c4 = self._path_cosines(wi, wo)
        Ri = self.substrate_reflectance(ci)
        Rr = self.substrate_reflectance(cr)
        s = self.phase(c1) + Ri * self.phase(c2) + Rr * self.phase(c3) + Ri * Rr * self.phase(c4)
        safe = np.where(above, ci * cr, 1.0)
        return np.where(above, self._attenuation(ci) * self._attenuation(cr) * s / safe, 0.0)

    def _path_probabilities(self, ci):
        """Path choice: ``(a_back, R_i, R_i, R_i^2 a_back)`` normalised, ``a_back`` the phase
        function's backward fraction (paths 1 and 4 reach the viewer only by backscatter; any
        positive mixture is unbiased, this one wastes fewer draws below the horizon)."""
        R = self.substrate_reflectance(ci)
        ab = self._table["back"]
        q = np.stack([np.full_like(R, ab), R, R, R * R * ab], axis=1)
        return q / q.sum(axis=1, keepdims=True)

    def _density(self, mu):
        t = self._table
        k = np.clip(np.searchsorted(t["mu"], mu, side="right") - 1, 0, len(t["density"]) - 1)
        return t["density"][k]

    def pdf(self, wi, wo, polarization: str = "u") -> np.ndarray:
        """Density per sr of :meth:`sample`: the path mixture of the tabulated phase function."""
        wi = np.asarray(wi, float)
        wo = np.asarray(wo, float)
        q = self._path_probabilities(wi[:, 2])
        cs = self._path_cosines(wi, wo)
        out = sum(q[:, j] * self._density(cs[j]) for j in range(4))
        return np.where((wi[:, 2] > 0) & (wo[:, 2] > 0), out, 0.0)

    def sample_direction(self, wi, u) -> np.ndarray:
        """Directions drawn from the path mixture (u : (n, 2) or (n, 3); the last two are used)."""
        t = self._table
        wi = np.asarray(wi, float)
        uu = direction_uniforms(u)
        u1, u2 = uu[:, 0], uu[:, 1]
        q = self._path_probabilities(wi[:, 2])
        cq = np.cumsum(q, axis=1)
        path = np.minimum((u1[:, None] >= cq).sum(axis=1), 3)
        lo = np.where(path > 0, np.take_along_axis(cq, np.maximum(path - 1, 0)[:, None], 1)[:, 0], 0.0)
        hi = np.take_along_axis(cq, path[:, None], 1)[:, 0]
        v = np.clip((u1 - lo) / np.maximum(hi - lo, 1e-300), 0.0, 1.0 - 1e-16)
        k = np.clip(np.searchsorted(t["cdf"], v, side="right") - 1, 0, len(t["density"]) - 1)
        frac = (v - t["cdf"][k]) / np.maximum(t["cdf"][k + 1] - t["cdf"][k], 1e-300)
        mu = t["mu"][k] + frac * (t["mu"][k + 1] - t["mu"][k])
        mu = np.clip(mu, -1.0, 1.0)
        kin = -wi
        axis = np.where((path % 2 == 1)[:, None], kin * np.array([1.0, 1.0, -1.0]), kin)
        # orthonormal frame about the axis
        helper = np.where(np.abs(axis[:, 2:3]) < 0.9, np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]]))
        e1 = np.cross(helper, axis)
        e1 /= np.linalg.norm(e1, axis=1)[:, None]
        e2 = np.cross(axis, e1)
        sin_t = np.sqrt(np.maximum(0.0, 1.0 - mu * mu))
        phi = 2.0 * np.pi * u2
        d = mu[:, None] * axis + (sin_t * np.cos(phi))[:, None] * e1 + (sin_t * np.sin(phi))[:, None] * e2
        d = np.where((path >= 2)[:, None], d * np.array([1.0, 1.0, -1.0]), d)
        return d

    def sample(self, wi, u, polarization: str = "u") -> Sample:
        """Draw from the path mixture; weight ``f cos / pdf`` (0 below the horizon)."""
        check_polarization(polarization)
        wi = np.asarray(wi, float)
        wo = self.sample_direction(wi, u)
        pdf = self.pdf(wi, wo)
        f = self.brdf(wi, wo)
        good = (wo[:, 2] > 0) & (wi[:, 2] > 0) & (pdf > 0)
        if not np.all(good):  # below the horizon: the horizon direction of the same azimuth, weight 0
            flat = wo[~good] * np.array([1.0, 1.0, 0.0])
            norm = np.linalg.norm(flat, axis=1)
            flat = np.where((norm > 1e-12)[:, None], flat / np.maximum(norm, 1e-300)[:, None], [1.0, 0.0, 0.0])
            wo = wo.copy()
            wo[~good] = flat
        weight = np.where(good, f * wo[:, 2] / np.where(good, pdf, 1.0), 0.0)
        return Sample(wo=wo, weight=weight, pdf_per_sr=np.where(good, pdf, 0.0))

    def to_dict(self) -> dict:
        d = {"type": "particulate", "level": self.level}
        if self.slope != 0.926:
            d["slope"] = self.slope
        if self.n != 1.5:
            d["n"] = list(self.n) if isinstance(self.n, tuple) else self.n
        if self.weight != 1.0:
            d["weight"] = self.weight
        if self.substrate_n is not None:
            d["substrate_n"] = list(self.substrate_n) if isinstance(self.substrate_n, tuple) else self.substrate_n
        if self.substrate_r is not None:
            d["substrate_r"] = self.substrate_r
        if self.wavelength_nm is not None:
            d["wavelength_nm"] = self.wavelength_nm
        return d
