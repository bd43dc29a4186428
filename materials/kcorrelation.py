"""K-correlation (ABC PSD) scatter lobe: Dittman's form and first-order Rayleigh-Rice.

Band-limited ABC power spectral density (PHYSICS §1), cycles convention, f in 1/length::

    S2(f) = A / (1 + (B f)^2)^(s/2),   B = 2 pi lc,   f = |beta - beta0| / lambda
    A = sigma^2 B^2 (s - 2) / (2 pi [1 - (1 + (B/lambda)^2)^(1 - s/2)])   (s = 2: sigma^2 B^2 / (pi ln(1 + (B/lambda)^2)))

so that the roughness over 0 <= f <= 1/lambda is sigma. The BRDF is::

    f = weight (16 pi^2 / lambda^4) cos(theta_i) cos(theta_r) Q S2(f)

which is Dittman's K-correlation BRDF with dn = 2 and the exponent s/2
(Proc. SPIE 6291, 62910R (2006); the seed paper's printed Eq. 5 lacks the s/2)
when Q is replaced by a constant reflectance R. With ``n`` (real, or ``[n, k]``)
Q is the Rayleigh-Rice polarization factor of the incident polarization including
out-of-plane terms (:func:`materials.fresnel.polarization_factor`); with ``r``, Q = r
for every polarization (FRED-compatible).

Parameters
----------
sigma_nm : float
    rms roughness band-limited to 0..1/lambda, nm (>= 0).
lc_um : float
    Correlation length, um (> 0); B = 2 pi lc.
s : float
    2-D spectral slope (> 0): far from specular the BRDF falls as |beta - beta0|^-s.
n : float or [n, k], optional
    Substrate refractive index (Rayleigh-Rice polarization factor).
r : float, optional
    Constant reflectance in [0, 1] instead of ``n``. Exactly one of ``n``, ``r``.
weight : float
    Multiplies the lobe (default 1).
wavelength_nm : float, optional
    Defaults to the material file's ``wavelength_nm`` (``Material`` fills it in).

Validity: smooth-surface limit ``(4 pi sigma cos(theta_i) / lambda)^2 << 1``. A
beta-centred lobe cannot produce the off-specular grazing peaks of matte paints
(PHYSICS §1); the model is symmetric about beta0 by construction.

Sampling: radial inverse CDF of ``(1 + B^2 r^2 / lambda^2)^(-s/2)`` about beta0
(PHYSICS §3) over r <= 1 + |beta0|; weight f cos / pdf; below the horizon weight 0.

References
----------
J. C. Stover, *Optical Scattering*, 3rd ed. (SPIE, 2012), ch. 4.
M. G. Dittman, "K-correlation power spectral density and surface scatter model",
Proc. SPIE 6291, 62910R (2006).
T. A. Germer, Appl. Opt. 36, 8798 (1997); NIST SCATMECH ``Microroughness_BRDF_Model``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Optional, Union

import numpy as np

from materials.base import MaterialError, PairGeometry, Sample, check_polarization
from materials.fresnel import complex_index, polarization_factor, scatter_azimuth
from materials.fit_params import REFRACTIVE_INDEX, FitParam
from materials.flags import ComponentFlags
from materials.registry import register
from materials.sampling import check_real, lobe_direction, lobe_pdf, lobe_sample, set_fields

def _slope_ratio(s: float, log1p_x: float) -> float:
    """``(s - 2) / [1 - (1 + X)^(1 - s/2)]`` with ``log1p_x = ln(1 + X)``; its limit 2 / ln(1 + X) at s = 2."""
    a = 1.0 - 0.5 * s
    if abs(a) < 5e-10:
        return 2.0 / log1p_x
    return 2.0 * a / math.expm1(a * log1p_x)


@register("k_correlation")
@dataclass(frozen=True)
class KCorrelation:
    """K-correlation lobe (Dittman / Rayleigh-Rice), CONTRACTS §5 ``k_correlation``."""

    sigma_nm: float
    lc_um: float
    s: float
    n: Optional[Union[float, tuple]] = None
    r: Optional[float] = None
    weight: float = 1.0
    wavelength_nm: Optional[float] = None

    flags = ComponentFlags.GLOSSY
    reciprocal = True
    #: fitted parameters (materials.fit_params), with the shared index n: sigma from a polished mirror
    #: to a rough black; lc from sub-wavelength to 1 mm; the PSD slope s of measured blacks and optics
    fit_params = (
        FitParam("sigma_nm", 1e-3, 300.0, True, 5.0, (0.3, 60.0)),
        FitParam("lc_um", 0.05, 1000.0, True, 10.0, (0.3, 200.0)),
        FitParam("s", 1.0, 6.0, False, 2.5, (1.5, 4.0)),
        REFRACTIVE_INDEX,
    )

    def __post_init__(self):
        o = "k_correlation"
        set_fields(
            self,
            sigma_nm=check_real(o, "sigma_nm", self.sigma_nm, lo=0.0),
            lc_um=check_real(o, "lc_um", self.lc_um, lo=0.0, lo_open=True),
            s=check_real(o, "s", self.s, lo=0.0, lo_open=True),
            weight=check_real(o, "weight", self.weight, lo=0.0),
        )
        if (self.n is None) == (self.r is None):
            raise MaterialError(f"{o}: give exactly one of 'n' (refractive index) or 'r' (constant reflectance)")
        if self.r is not None:
            set_fields(self, r=check_real(o, "r", self.r, lo=0.0, hi=1.0))
        else:
            n = self.n
            if isinstance(n, (list, tuple)):
                if len(n) != 2:
                    raise MaterialError(f"{o}: parameter 'n' must be a number or [n, k], got {n!r}")
                n = (
                    check_real(o, "n[0]", n[0], lo=0.0, lo_open=True),
                    check_real(o, "n[1]", n[1], lo=0.0),
                )
                if n[1] == 0.0:
                    n = n[0]
            else:
                n = check_real(o, "n", n, lo=0.0, lo_open=True)
            set_fields(self, n=n)
        if self.wavelength_nm is not None:
            set_fields(self, wavelength_nm=check_real(o, "wavelength_nm", self.wavelength_nm, lo=0.0, lo_open=True))

    @classmethod
    def example(cls) -> "KCorrelation":
        """The PHYSICS §1 golden-table lobe (sigma 10 nm, lc 2 um, s 2.6, n 1.5, 532 nm)."""
        return cls(sigma_nm=10.0, lc_um=2.0, s=2.6, n=1.5, wavelength_nm=532.0)

    # ------------------------------------------------------------ derived constants

    def _wavelength(self) -> float:
        if self.wavelength_nm is None:
            raise MaterialError(
                "k_correlation: no wavelength_nm (give it in the component or in the material file)"
            )
        return self.wavelength_nm

    @cached_property
    def b_nm(self) -> float:
        """B = 2 pi lc, nm."""
        return 2.0 * math.pi * self.lc_um * 1e3

    @cached_property
    def width(self) -> float:
        """Lobe half-width in beta space, l = lambda / B (dimensionless)."""
        return self._wavelength() / self.b_nm

    @cached_property
    def psd_a_nm4(self) -> float:
        """A of the band-limited ABC PSD, nm^4 (PHYSICS §1)."""
        lam = self._wavelength()
        x = math.log1p((self.b_nm / lam) ** 2)
        # sigma^2 B^2 (s-2) / (2 pi [1 - (1+X)^(1-s/2)]) ; s = 2: sigma^2 B^2 / (pi ln(1+X))
        return self.sigma_nm**2 * self.b_nm**2 * _slope_ratio(self.s, x) / (2.0 * math.pi)

    @cached_property
    def prefactor(self) -> float:
        """weight * 16 pi^2 A / lambda^4 (1/sr): BRDF = prefactor Q cos_i cos_r shape."""
        return self.weight * 16.0 * math.pi**2 * self.psd_a_nm4 / self._wavelength() ** 4

    @cached_property
    def _index(self) -> complex:
        return complex_index(self.n) if self.n is not None else 0j

    # ------------------------------------------------------------ protocol

    def polarization_factor(self, wi, wo, polarization: str = "u") -> np.ndarray:
        """Q: the constant r, or the Rayleigh-Rice factor for the substrate index."""
        if self.r is not None:
            return np.full(len(wi), self.r)
        cos_phi, sin_phi = scatter_azimuth(wi, wo)
        return polarization_factor(wi[:, 2], wo[:, 2], cos_phi, sin_phi, self._index, polarization)

    #: brdf and pdf take ``pair=`` (a :class:`materials.base.PairGeometry` shared by a composite's lobes)
    pair_geometry = True

    def brdf(self, wi, wo, polarization: str = "u", pair=None) -> np.ndarray:
        """BRDF in 1/sr (no cos), (n,). wi, wo : (n, 3) unit vectors, sample frame; ``pair``: their
        :class:`materials.base.PairGeometry` when a composite shares it among its lobes (the same bits)."""
        check_polarization(polarization)
        g = PairGeometry(wi, wo) if pair is None else pair
        wi, wo, above, r2 = g.wi, g.wo, g.above(), g.r2()
        w2 = self.width**2
        shape = g.get(("shape", self.s, w2), lambda: np.exp(-0.5 * self.s * np.log1p(r2 / w2)))
        cos_i = g.get("cos_i", lambda: np.where(above, wi[:, 2], 0.0))
        cos_r = g.get("cos_r", lambda: np.where(above, wo[:, 2], 0.0))
        if self.r is not None:
            q = self.r
        else:
            def factor():
                cos_phi, sin_phi = g.get("azimuth", lambda: scatter_azimuth(wi, wo))
                return polarization_factor(cos_i, cos_r, cos_phi, sin_phi, self._index, polarization)
            q = g.get(("rayleigh_rice", self._index, polarization), factor)
        return self.prefactor * q * cos_i * cos_r * shape

    def sample(self, wi, u, polarization: str = "u") -> Sample:
        """Radial inverse-CDF draw about beta0; weight f cos / pdf (0 below the horizon)."""
        check_polarization(polarization)
        return lobe_sample(self, wi, u, polarization, self.width, self.s)

    def sample_direction(self, wi, u) -> np.ndarray:
        """The directions ``sample`` would draw, without weights (used by composites)."""
        return lobe_direction(wi, u, self.width, self.s)

    def pdf(self, wi, wo, polarization: str = "u", pair=None) -> np.ndarray:
        return lobe_pdf(wi, wo, self.width, self.s, pair)

    def to_dict(self) -> dict:
        out = {"type": "k_correlation", "sigma_nm": self.sigma_nm, "lc_um": self.lc_um, "s": self.s}
        if self.n is not None:
            out["n"] = list(self.n) if isinstance(self.n, tuple) else self.n
        else:
            out["r"] = self.r
        if self.weight != 1.0:
            out["weight"] = self.weight
        if self.wavelength_nm is not None:
            out["wavelength_nm"] = self.wavelength_nm
        return out

    def total_integrated_scatter(self) -> float:
        """Smooth-surface TIS at normal incidence for constant R: R (4 pi sigma / lambda)^2 (Stover Eq. 2.8)."""
        r = self.r if self.r is not None else abs((1 - self._index) / (1 + self._index)) ** 2
        return self.weight * r * (4 * math.pi * self.sigma_nm / self._wavelength()) ** 2
