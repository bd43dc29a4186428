"""The fitted sample as the diagnosis evaluates it, fast: Lambertian + K-correlation lobes on
cached quadrature-node geometry, and the cache of the rig's nodes per (config, scan points)."""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from types import SimpleNamespace

import numpy as np

from materials.kcorrelation import KCorrelation
from rig.forward import node_groups
from rig.node_integrals import cached_integral


def q_factor_real(cos_i, cos_r, cos_phi, sin_phi, n: float, pol: str) -> np.ndarray:
    """Rayleigh-Rice polarization factor Q (PHYSICS §1, Germer 1997) for a real index n > 1,
    in real arithmetic. Same formulas as :func:`materials.fresnel.polarization_factor`
    (checked against it in the tests); used here because the fit evaluates it millions of times."""
    eps = n * n
    sin_i = np.sqrt(np.maximum(0.0, 1.0 - cos_i * cos_i))
    sin_r = np.sqrt(np.maximum(0.0, 1.0 - cos_r * cos_r))
    qi = np.sqrt(eps - sin_i * sin_i)
    qr = np.sqrt(eps - sin_r * sin_r)
    e1 = eps - 1.0
    di_s = cos_i + qi
    di_p = eps * cos_i + qi
    dr_s = cos_r + qr
    dr_p = eps * cos_r + qr
    qs = qp = None
    if pol in ("s", "u"):
        qs = (e1 / (di_s * dr_s) * cos_phi) ** 2 + (e1 * qr / (di_s * dr_p) * sin_phi) ** 2
        if pol == "s":
            return qs
    qp = (e1 * (qi * qr * cos_phi - eps * sin_i * sin_r) / (di_p * dr_p)) ** 2 + (e1 * qi / (di_p * dr_s) * sin_phi) ** 2
    if pol == "p":
        return qp
    return 0.5 * (qs + qp)


def node_geometry(wi, wo) -> dict:
    """Material-independent quantities of direction pairs, computed once per rig.

    ``wi`` and ``wo`` are (..., 3) and broadcast together: the cache passes wi as
    (n_points, 1, 3) and wo as (n_points, n_nodes, 3), so the incidence terms are computed
    once per point (the rig's nodes share their point's incidence)."""
    wix, wiy, cos_i = wi[..., 0], wi[..., 1], wi[..., 2]
    wox, woy, cos_o = wo[..., 0], wo[..., 1], wo[..., 2]
    dx, dy = wox + wix, woy + wiy
    tn = np.hypot(wix, wiy)
    ok = tn > 1e-15
    inv_t = 1.0 / np.where(ok, tn, 1.0)
    tx = np.where(ok, -wix * inv_t, 1.0)
    ty = np.where(ok, -wiy * inv_t, 0.0)
    on = np.hypot(wox, woy)
    ok_o = on > 1e-15
    inv = 1.0 / np.where(ok_o, on, 1.0)
    cos_phi = np.where(ok_o, (wox * tx + woy * ty) * inv, 1.0)
    sin_phi = np.where(ok_o, (tx * woy - ty * wox) * inv, 0.0)
    above = (cos_i > 0) & (cos_o > 0)
    r2 = dx * dx + dy * dy
    return {"cos_i": cos_i, "cos_o": cos_o, "r2": r2, "r2_f32": r2.astype(np.float32), "cos_phi": cos_phi,
            "sin_phi": sin_phi, "above": above, "q_cache": {}, "int_cache": {}}


@lru_cache(maxsize=4096)
def _lobe_constants(sigma_nm, lc_um, s, n, wavelength_nm):
    """The K-correlation lobe's constants (``prefactor``, ``width``, ``s``) for one parameter set;
    cached because the fit asks for the same lobe thousands of times (building a
    KCorrelation validates its inputs each time)."""
    kc = KCorrelation(sigma_nm=sigma_nm, lc_um=lc_um, s=s, n=n, wavelength_nm=wavelength_nm)
    return SimpleNamespace(prefactor=kc.prefactor, width=kc.width, s=kc.s)


@dataclass(frozen=True, eq=False)
class FitMaterial:
    """Lambertian + K-correlation lobes with one shared real index n (the fitted sample).

    ``lobes``: tuple of (sigma_nm, lc_um, s). Constants (PSD normalisation, prefactor) come
    from :class:`materials.kcorrelation.KCorrelation`; :meth:`brdf_geom` evaluates the same
    BRDF from cached node geometry (see :func:`node_geometry`).
    """

    rd: float
    lobes: tuple
    n: float
    wavelength_nm: float

    supports_geom = True

    def _kc(self):
        return [_lobe_constants(s, l, sl, self.n, self.wavelength_nm) for s, l, sl in self.lobes]

    def brdf(self, wi, wo, polarization="u"):
        return self.brdf_geom(node_geometry(np.asarray(wi, float), np.asarray(wo, float)), polarization)

    def _q(self, geom, polarization):
        key = (self.n, polarization)
        q = geom["q_cache"].get(key)
        if q is None:
            if len(geom["q_cache"]) > 4:
                geom["q_cache"].clear()
            q = q_factor_real(geom["cos_i"], geom["cos_o"], geom["cos_phi"], geom["sin_phi"], self.n, polarization)
            q = np.where(geom["above"], q * geom["cos_i"] * geom["cos_o"], 0.0)
            geom["q_cache"][key] = q
        return q

    def brdf_geom(self, geom, polarization="u"):
        """BRDF at cached node geometry (same values as :meth:`brdf`)."""
        cc = self._q(geom, polarization)
        out = np.where(geom["above"], self.rd / math.pi, 0.0)
        for kc in self._kc():
            out = out + kc.prefactor * cc * np.exp(-0.5 * kc.s * np.log1p(geom["r2"] / kc.width**2))
        return out

    def reading_geom(self, geom, weight, polarization="u"):
        """The instrument reading sum(weight * f) per point, with per-component caching."""
        out = self.rd / math.pi * cached_integral(geom, weight, ("lambert",), lambda: geom["above"].astype(float))
        for kc in self._kc():
            def lobe(kc=kc):
                # float32 exp(log): 4x faster than float64 power (SIMD exp and log), 4e-7 relative,
                # far below the fit's finite-difference steps
                t = geom["r2_f32"] * np.float32(1.0 / kc.width**2)
                t += np.float32(1.0)
                np.log(t, out=t)
                t *= np.float32(-0.5 * kc.s)
                np.exp(t, out=t)
                return self._q(geom, polarization) * t
            out = out + kc.prefactor * cached_integral(geom, weight, ("lobe", kc.width, kc.s, self.n, polarization), lobe)
        return out

    def to_dict(self) -> dict:
        """Material file (CONTRACTS §5)."""
        comps = [{"type": "lambertian", "rd": self.rd}]
        for s, l, sl in self.lobes:
            comps.append({"type": "k_correlation", "sigma_nm": s, "lc_um": l, "s": sl, "n": self.n})
        return {"name": "fitted_through_rig", "wavelength_nm": self.wavelength_nm, "components": comps}


class NodeCache:
    """The instrument forward model (the same rules as :func:`rig.forward.instrument_forward`)
    with its quadrature nodes and node geometry cached per (rig config, scan points)."""

    def __init__(self, max_entries: int = 12):
        self._store: dict = {}
        self.max_entries = max_entries

    def _entry(self, theta_i, theta_r, phi_r, pol, config):
        key = (config, theta_i.tobytes(), theta_r.tobytes(), phi_r.tobytes(), pol.tobytes())
        entry = self._store.get(key)
        if entry is None:
            entry = []
            for code in ("s", "p", "u"):
                sel = np.flatnonzero(pol == code)
                if sel.size == 0:
                    continue
                for idx, wi, wo, weight in node_groups(theta_i[sel], theta_r[sel], phi_r[sel], config):
                    m = len(idx)
                    if wi.size == 3 * m:  # one incidence per point: (m, 1, 3) against (m, nodes, 3)
                        wi2, wo2 = wi.reshape(m, 1, 3), wo.reshape(m, -1, 3)
                    else:
                        wi2, wo2 = (a.reshape(m, -1, 3) for a in np.broadcast_arrays(wi, wo))
                    entry.append((code, sel[idx], weight.reshape(m, -1), node_geometry(wi2, wo2), wi2, wo2))
            if len(self._store) >= self.max_entries:
                self._store.pop(next(iter(self._store)))
            self._store[key] = entry
        return entry

    def __call__(self, theta_i, theta_r, phi_r, pol, config, material):
        out = np.zeros(theta_i.shape[0])
        for code, sel, weight, geom, wi, wo in self._entry(theta_i, theta_r, phi_r, pol, config):
            if getattr(material, "supports_geom", False):
                out[sel] = material.reading_geom(geom, weight, code)
            else:
                wi_b, wo_b = np.broadcast_arrays(wi, wo)
                f = np.asarray(material.brdf(wi_b.reshape(-1, 3), wo_b.reshape(-1, 3), code), float)
                out[sel] = np.einsum("nk,nk->n", weight, f.reshape(weight.shape))
        return out
