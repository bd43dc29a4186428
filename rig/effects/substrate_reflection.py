"""Light reflected by the substrate under a thin semi-transparent coating (CONTRACTS §3
``substrate_reflection``).

Part of the beam is refracted into the coating (index ``n1``, the sample's own), crosses it,
reflects at the coating/substrate interface (silicon, ``n2 = 4.15 + 0.044i`` at 532 nm), is
attenuated there and back along the slant path, and is refracted out parallel to the specular
ray: a ghost of the specular beam. Incoherent sum over the bounces inside the coating
(Born & Wolf §1.6 for the interfaces; Heavens, *Optical properties of thin solid films*, for
the incoherent layer)::

    G(theta_i, pol) = T01^2 R12 A / (1 - R01 R12 A),     A = transmittance^(2 / cos theta_t)

with ``T01 = 1 - R01`` the air/coating Fresnel transmittance at ``theta_i``, ``R01`` also the
coating/air reflectance seen from inside at ``theta_t`` (``sin theta_i = n1 sin theta_t``),
``R12`` the coating/silicon Fresnel reflectance at ``theta_t`` and ``transmittance`` the
coating's one-way power transmittance at normal incidence (``exp(-alpha d)``; the path is
``d / cos theta_t`` each way). s and p are computed separately (``u`` is their mean). The
silicon interface has no Brewster zero inside the coating (its Brewster angle,
atan(4.15 / n1) ~ 70 deg, lies beyond the largest refraction angle, asin(1 / n1)), so the
ghost fills the p dip the coating's own surface has near its Brewster angle (56 deg for 1.5).

The ghost leaves around the specular direction, blurred by the interfaces: in projected
coordinates (cos theta_r dOmega = d beta_x d beta_y, PHYSICS §3)::

    f_ghost = G / (2 pi w^2) exp(-|beta - beta_spec|^2 / (2 w^2)),   w = lobe_width_deg x cos(theta_i)

so the lobe returns the fraction G of the incident power and is ``lobe_width_deg`` wide in
viewing angle. It is added to the material before the instrument averaging.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from materials.fresnel import fresnel_power
from rig.effects.registry import check_param, register_effect
from rig.node_integrals import cached_integral

#: Silicon at 532 nm (Green 2008, Sol. Energy Mater. Sol. Cells 92, 1305: n 4.15, k 0.044).
SILICON_532NM = complex(4.15, 0.044)
#: Coating index used when the sample model does not carry one.
DEFAULT_COATING_N = 1.5


def ghost_fraction(cos_i, polarization: str, coating_n: float, transmittance: float,
                   substrate_n: complex = SILICON_532NM) -> np.ndarray:
    """The power fraction G returned by the substrate (module doc), per incidence cosine."""
    c = np.clip(np.asarray(cos_i, float), 1e-9, 1.0)
    n1 = float(coating_n)
    cos_t = np.sqrt(1.0 - (1.0 - c * c) / (n1 * n1))
    rs01, rp01, _, _ = fresnel_power(c, n1)
    rs12, rp12, _, _ = fresnel_power(cos_t, complex(substrate_n) / n1)
    a = float(transmittance) ** (2.0 / cos_t)

    def one(r01, r12):
        return (1.0 - r01) ** 2 * r12 * a / (1.0 - r01 * r12 * a)

    if polarization == "s":
        return one(rs01, rs12)
    if polarization == "p":
        return one(rp01, rp12)
    return 0.5 * (one(rs01, rs12) + one(rp01, rp12))


def coating_index(material) -> float:
    """The coating's refractive index: the sample model's own ``n`` (a fitted material, or the
    first component that has one), else :data:`DEFAULT_COATING_N`."""
    n = getattr(material, "n", None)
    if isinstance(n, (int, float)) and n > 1.0:
        return float(n)
    for comp in getattr(material, "components", ()) or ():
        n = getattr(comp, "n", None)
        if isinstance(n, (int, float)) and n > 1.0:
            return float(n)
        if isinstance(n, complex) and n.real > 1.0:
            return float(n.real)
    return DEFAULT_COATING_N


@dataclass(frozen=True, eq=False)
class _WithSubstrate:
    """A material plus the substrate's ghost lobe (Brdf protocol, and the diagnosis's cached
    node geometry)."""

    material: object
    transmittance: float
    width_rad: float
    coating_n: float
    substrate_n: complex

    def _fraction(self, cos_i, polarization):
        return ghost_fraction(cos_i, polarization, self.coating_n, self.transmittance, self.substrate_n)

    def brdf_geom(self, geom, polarization="u"):
        """Same as :meth:`brdf` from cached node geometry (rig.diagnose.fast_material.node_geometry)."""
        base = self.material.brdf_geom(geom, polarization)
        cos_i = np.clip(geom["cos_i"], 1e-6, None)
        w = self.width_rad * cos_i
        lobe = self._fraction(cos_i, polarization) / (2 * math.pi * w**2) * np.exp(-0.5 * geom["r2"] / w**2)
        return base + np.where(geom["above"], lobe, 0.0)

    def reading_geom(self, geom, weight, polarization="u"):
        """Instrument reading from cached node geometry (rig.diagnose.fast_material.NodeCache). With one
        incidence per point the ghost fraction factors out and the unit lobe's integral is cached per
        width; with per-node incidences (a diverging beam) it is integrated node by node."""
        cos_i = np.clip(geom["cos_i"], 1e-6, None)

        def unit_lobe():
            w = self.width_rad * cos_i
            return np.where(geom["above"], np.exp(-0.5 * geom["r2"] / w**2) / (2 * math.pi * w**2), 0.0)

        base = self.material.reading_geom(geom, weight, polarization)
        if cos_i.ndim == 2 and cos_i.shape[1] == 1:  # one incidence per point
            frac = self._fraction(cos_i[:, 0], polarization)
            return base + frac * cached_integral(geom, weight, ("substrate", self.width_rad), unit_lobe)
        frac = self._fraction(cos_i, polarization)
        key = ("substrate", self.width_rad, self.transmittance, self.coating_n, polarization)
        return base + cached_integral(geom, weight, key, lambda: frac * unit_lobe())

    @property
    def supports_geom(self) -> bool:
        return getattr(self.material, "supports_geom", False)

    def brdf(self, wi, wo, polarization="u"):
        wi, wo = np.asarray(wi, float), np.asarray(wo, float)
        base = self.material.brdf(wi, wo, polarization)
        d = wo[:, :2] + wi[:, :2]
        cos_i = np.clip(wi[:, 2], 1e-6, None)
        w = self.width_rad * cos_i
        lobe = self._fraction(cos_i, polarization) / (2 * math.pi * w**2) * np.exp(-0.5 * (d[:, 0] ** 2 + d[:, 1] ** 2) / w**2)
        return base + np.where((wo[:, 2] > 0) & (wi[:, 2] > 0), lobe, 0.0)


@register_effect("substrate_reflection")
@dataclass(frozen=True)
class SubstrateReflection:
    """Ghost from the substrate under a thin coating (module doc): ``transmittance`` is the
    coating's one-way power transmittance at normal incidence (0 = opaque, no ghost),
    ``lobe_width_deg`` the ghost's Gaussian sigma in viewing angle; ``coating_n`` (default: the
    sample model's own index) and the substrate's complex index (default silicon at 532 nm)."""

    transmittance: float = 0.0
    lobe_width_deg: float = 0.5
    coating_n: float | None = None
    substrate_n: float = SILICON_532NM.real
    substrate_k: float = SILICON_532NM.imag

    fit_space = {
        "transmittance": (1e-3, 1.0, "log", (0.03, 0.3)),
        "lobe_width_deg": (0.05, 10.0, "log", (0.3, 1.5)),
    }
    region = "shoulder"
    #: known from the sample, not fitted
    fixed = ("coating_n", "substrate_n", "substrate_k")

    def __post_init__(self):
        name = "substrate_reflection"
        object.__setattr__(self, "transmittance", check_param(name, "transmittance", self.transmittance, 0.0, 1.0))
        object.__setattr__(self, "lobe_width_deg", check_param(name, "lobe_width_deg", self.lobe_width_deg, 1e-6, 90.0))
        object.__setattr__(self, "coating_n", check_param(name, "coating_n", self.coating_n, 1.0, 5.0, allow_none=True))
        object.__setattr__(self, "substrate_n", check_param(name, "substrate_n", self.substrate_n, 0.01, 20.0))
        object.__setattr__(self, "substrate_k", check_param(name, "substrate_k", self.substrate_k, 0.0, 50.0))

    def wrap(self, forward):
        if self.transmittance == 0.0:
            return forward
        t, width = self.transmittance, math.radians(self.lobe_width_deg)
        n2 = complex(self.substrate_n, self.substrate_k)
        fixed_n = self.coating_n

        def wrapped(theta_i, theta_r, phi_r, pol, config, material):
            n1 = fixed_n if fixed_n is not None else coating_index(material)
            return forward(theta_i, theta_r, phi_r, pol, config, _WithSubstrate(material, t, width, n1, n2))

        return wrapped
