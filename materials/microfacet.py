"""Cook-Torrance / Walter microfacet lobe with the GGX distribution (component ``"microfacet"``).

    f(wi, wo) = weight * D(h) G2(wi, wo) F(wi . h) / (4 cos theta_i cos theta_r)

with the half vector ``h = (wi + wo) / |wi + wo|`` (Walter et al. 2007, Eq. 20), the
GGX (Trowbridge-Reitz) distribution of normals

    D(h) = alpha^2 / (pi (1 + (alpha^2 - 1) h_z^2)^2)          (Walter Eq. 33)

the height-correlated Smith shadowing-masking term (Heitz 2014, Eq. 99)

    G2 = 1 / (1 + Lambda(wi) + Lambda(wo)),  Lambda(w) = (sqrt(1 + alpha^2 tan^2 theta) - 1) / 2

and the Fresnel reflectance of a dielectric or metal of index ``n`` (real, or
``[n, k]``) at the microfacet angle ``wi . h``, for the incident polarization
resolved on the facet's own s/p basis (:meth:`Microfacet.fresnel`): in the plane of
incidence s incidence sees ``R_s`` and p sees ``R_p``; ``u`` sees their mean.

Why it is here: a matte black paint scatters a grazing *forward* lobe that peaks
beyond the specular direction (the real Z307 data: 0.48 1/sr at 75 deg vs 0.27 at
70 deg for 70 deg incidence). A beta-centred lobe (K-correlation, ABg) cannot do
that; the 1/cos(theta_r) of the microfacet form, Fresnel growth and shadowing can.

Single scattering only: the lobe loses the energy that would be multiply scattered
between facets (so rho < 1 always holds; it is an underestimate for large alpha).

Sampling draws visible normals (Heitz 2018, "Sampling the GGX Distribution of
Visible Normals", JCGT 7(4)), so ``pdf = D(h) G1(wi) / (4 cos theta_i)`` and the
weight ``f cos theta_r / pdf = weight F G2 / G1(wi)`` is at most ``weight``.
Reflected directions below the horizon get weight 0 (never re-drawn).

Keys: ``alpha`` (GGX width, dimensionless, 1e-4..4), ``n`` (index, or ``[n, k]``),
``weight`` (default 1, multiplies the lobe).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from materials.base import MaterialError, Sample, check_polarization
from materials.fit_params import REFRACTIVE_INDEX, FitParam
from materials.flags import ComponentFlags
from materials.registry import register


def _check_number(name, value, lo, hi):
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise MaterialError(f"microfacet: parameter {name!r} must be a number, got {value!r}")
    v = float(value)
    if not (lo <= v <= hi):
        raise MaterialError(f"microfacet: parameter {name!r} = {v!r} is outside [{lo}, {hi}]")
    return v


def fresnel_rs_rp(cos_theta, n):
    """Fresnel power reflectances (R_s, R_p) at incidence cosine ``cos_theta`` from air
    onto a medium of complex index ``n`` (Born & Wolf §1.5; absorbing media §14.2)."""
    c = np.clip(np.asarray(cos_theta, float), 0.0, 1.0)
    eps = complex(n) ** 2
    q = np.sqrt(eps - (1.0 - c * c) + 0j)  # n cos(theta_t), principal root (Im >= 0)
    rs = (c - q) / (c + q)
    rp = (eps * c - q) / (eps * c + q)
    return np.abs(rs) ** 2, np.abs(rp) ** 2


@register("microfacet")
@dataclass(frozen=True)
class Microfacet:
    """GGX microfacet specular lobe (see module docstring for formulas and references).

    Parameters
    ----------
    alpha : float
        GGX roughness width, dimensionless (tan of the facet tilt at which D halves ~ alpha).
    n : float or [n, k]
        Refractive index of the facets (Fresnel at the facet angle).
    weight : float
        Multiplies the lobe (default 1).
    """

    alpha: float
    n: object = 1.5
    weight: float = 1.0

    flags = ComponentFlags.GLOSSY
    reciprocal = True  # for unpolarized light; s/p are reciprocal in the plane of incidence only
    #: fitted parameters (materials.fit_params), with the shared index n
    fit_params = (
        FitParam("alpha", 1e-3, 2.0, True, 0.3, (0.05, 1.0)),
        FitParam("weight", 1e-6, 1e3, True, 1.0, (0.05, 20.0)),
        REFRACTIVE_INDEX,
    )

    def __post_init__(self):
        object.__setattr__(self, "alpha", _check_number("alpha", self.alpha, 1e-4, 4.0))
        object.__setattr__(self, "weight", _check_number("weight", self.weight, 0.0, 1e6))
        n = self.n
        if isinstance(n, (list, tuple)):
            if len(n) != 2:
                raise MaterialError(f"microfacet: parameter 'n' must be a number or [n, k], got {n!r}")
            n = [_check_number("n", n[0], 1e-3, 100.0), _check_number("n[k]", n[1], 0.0, 100.0)]
        else:
            n = _check_number("n", n, 1.0001, 100.0)
        object.__setattr__(self, "n", n)

    @classmethod
    def example(cls) -> "Microfacet":
        return cls(alpha=0.3, n=1.5, weight=1.0)

    def to_dict(self) -> dict:
        out = {"type": "microfacet", "alpha": self.alpha, "n": list(self.n) if isinstance(self.n, list) else self.n}
        if self.weight != 1.0:
            out["weight"] = self.weight
        return out

    # ------------------------------------------------------------------ pieces
    @property
    def _n_complex(self) -> complex:
        return complex(self.n[0], self.n[1]) if isinstance(self.n, list) else complex(self.n)

    def distribution(self, cos_h):
        """GGX D(h) per sr of facet normal, given cos(theta_h)."""
        a2 = self.alpha**2
        c2 = np.asarray(cos_h, float) ** 2
        return np.where(c2 > 0, a2 / (np.pi * (1.0 + (a2 - 1.0) * c2) ** 2), 0.0)

    def smith_lambda(self, cos_theta):
        """Smith Lambda for GGX; cos_theta of a direction above the horizon."""
        c2 = np.clip(np.asarray(cos_theta, float) ** 2, 1e-300, 1.0)
        tan2 = (1.0 - c2) / c2
        return 0.5 * (np.sqrt(1.0 + self.alpha**2 * tan2) - 1.0)

    def fresnel(self, wi, h, polarization: str):
        """Reflected power fraction of one facet (normal h) for the incident polarization.

        The sample's s vector ``e_s ~ z x wi`` (y at normal incidence, CONTRACTS §1) is
        split over the facet's own s/p basis (``s_h ~ wi x h``): with ``c2 = (e_s . s_h)^2``,
        s incidence reflects ``c2 R_s + (1 - c2) R_p`` and p incidence ``(1 - c2) R_s + c2 R_p``
        (exact power for a linear polarization and no analyser). In the plane of incidence
        c2 = 1; u is the mean (R_s + R_p) / 2.
        """
        cos_d = np.einsum("ij,ij->i", wi, h)
        rs, rp = fresnel_rs_rp(cos_d, self._n_complex)
        if polarization == "u":
            return 0.5 * (rs + rp)
        e_s = np.stack([-wi[:, 1], wi[:, 0], np.zeros(len(wi))], axis=-1)
        norm = np.linalg.norm(e_s, axis=1)
        e_s = np.where(norm[:, None] > 1e-12, e_s / np.where(norm > 1e-12, norm, 1.0)[:, None], [0.0, 1.0, 0.0])
        s_h = np.cross(wi, h)
        norm_h = np.linalg.norm(s_h, axis=1)
        c2 = np.where(norm_h > 1e-12, np.einsum("ij,ij->i", e_s, s_h) ** 2 / np.where(norm_h > 1e-12, norm_h, 1.0) ** 2, 1.0)
        if polarization == "s":
            return c2 * rs + (1.0 - c2) * rp
        return (1.0 - c2) * rs + c2 * rp

    # ------------------------------------------------------------------ protocol
    def brdf(self, wi, wo, polarization: str = "u"):
        """Walter Eq. 20 (reflection), 1/sr, no cos; zero when either direction is below the horizon."""
        check_polarization(polarization)
        wi = np.asarray(wi, float)
        wo = np.asarray(wo, float)
        ci, co = wi[:, 2], wo[:, 2]
        ok = (ci > 0) & (co > 0)
        hv = wi + wo
        hn = np.linalg.norm(hv, axis=1)
        h = hv / np.where(hn > 0, hn, 1.0)[:, None]
        d = self.distribution(h[:, 2])
        g2 = 1.0 / (1.0 + self.smith_lambda(ci) + self.smith_lambda(co))
        f = self.fresnel(wi, h, polarization)
        denom = 4.0 * np.where(ok, ci * co, 1.0)
        return np.where(ok & (hn > 0), self.weight * d * g2 * f / denom, 0.0)

    def _sample_visible_normal(self, wi, u2):
        """Heitz 2018 Listing 1 (isotropic alpha): facet normals (n, 3) seen from wi."""
        a = self.alpha
        v = np.stack([a * wi[:, 0], a * wi[:, 1], wi[:, 2]], axis=-1)
        v /= np.linalg.norm(v, axis=1)[:, None]
        lensq = v[:, 0] ** 2 + v[:, 1] ** 2
        inv = np.where(lensq > 0, 1.0 / np.sqrt(np.where(lensq > 0, lensq, 1.0)), 0.0)
        t1 = np.where(lensq[:, None] > 0, np.stack([-v[:, 1] * inv, v[:, 0] * inv, np.zeros_like(inv)], -1),
                      np.array([1.0, 0.0, 0.0]))
        t2 = np.cross(v, t1)
        r = np.sqrt(u2[:, 0])
        phi = 2.0 * np.pi * u2[:, 1]
        p1 = r * np.cos(phi)
        p2 = r * np.sin(phi)
        s = 0.5 * (1.0 + v[:, 2])
        p2 = (1.0 - s) * np.sqrt(np.maximum(0.0, 1.0 - p1 * p1)) + s * p2
        p3 = np.sqrt(np.maximum(0.0, 1.0 - p1 * p1 - p2 * p2))
        nh = p1[:, None] * t1 + p2[:, None] * t2 + p3[:, None] * v
        ne = np.stack([a * nh[:, 0], a * nh[:, 1], np.maximum(1e-12, nh[:, 2])], axis=-1)
        return ne / np.linalg.norm(ne, axis=1)[:, None]

    def sample(self, wi, u, polarization: str = "u") -> Sample:
        """Visible-normal sampling; weight = f cos(theta_r) / pdf (= weight F G2 / G1(wi))."""
        check_polarization(polarization)
        wi = np.asarray(wi, float)
        u = np.asarray(u, float)
        if u.ndim != 2 or u.shape[1] not in (2, 3):
            raise ValueError(f"uniforms u must have shape (n, 2) or (n, 3), got {u.shape}")
        u2 = u[:, -2:]
        ok_i = wi[:, 2] > 0
        wi_up = np.where(ok_i[:, None], wi, np.array([0.0, 0.0, 1.0]))
        h = self._sample_visible_normal(wi_up, u2)
        cos_d = np.einsum("ij,ij->i", wi_up, h)
        wo = 2.0 * cos_d[:, None] * h - wi_up
        wo /= np.linalg.norm(wo, axis=1)[:, None]
        pdf = self.pdf(wi, wo, polarization)
        f = self.brdf(wi, wo, polarization)
        good = ok_i & (wo[:, 2] > 0) & (pdf > 0)
        weight = np.where(good, f * np.maximum(wo[:, 2], 0.0) / np.where(good, pdf, 1.0), 0.0)
        return Sample(wo=wo, weight=weight, pdf_per_sr=np.where(good, pdf, 0.0))

    def pdf(self, wi, wo, polarization: str = "u"):
        """D(h) G1(wi) / (4 cos theta_i) per sr (Heitz 2018 Eq. 17 with the reflection Jacobian)."""
        wi = np.asarray(wi, float)
        wo = np.asarray(wo, float)
        ci = wi[:, 2]
        ok = (ci > 0) & (wo[:, 2] > 0)
        hv = wi + wo
        hn = np.linalg.norm(hv, axis=1)
        hz = hv[:, 2] / np.where(hn > 0, hn, 1.0)
        g1 = 1.0 / (1.0 + self.smith_lambda(ci))
        return np.where(ok & (hn > 0), self.distribution(hz) * g1 / (4.0 * np.where(ok, ci, 1.0)), 0.0)
