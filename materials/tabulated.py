"""Tabulated in-plane BRDF (e.g. a measured scan), extended out of plane about beta0.

Keys (material file, CONTRACTS §5 "further component types")::

    {"type": "tabulated",
     "theta_i_deg": [10, 30, 70],                 # strictly increasing, in [0, 90)
     "theta_r_deg": [-80, ..., 0, ..., 85],       # strictly increasing, in [-90, 90]; signed:
                                                  #   > 0 specular half-plane (phi_r = 0),
                                                  #   < 0 backscatter half-plane (phi_r = 180)
     "brdf_per_sr": [[...], [...], [...]],        # (len(theta_i_deg), len(theta_r_deg)), >= 0
     "brdf_s_per_sr": [[...]], "brdf_p_per_sr": [[...]]}   # optional, same shape

``brdf_per_sr`` serves every polarization unless ``brdf_s_per_sr`` / ``brdf_p_per_sr``
are given (then s and p use them, and u uses ``brdf_per_sr`` if present, else their mean).
At least one of ``brdf_per_sr`` or both s and p tables is required.

Interpolation: bilinear in (theta_i, theta_r) on log10(BRDF) when every entry is
positive (BRDFs span decades), on the BRDF itself otherwise. Outside the table the
edge value is held (no extrapolation).

Out of plane (a modelling assumption, stated honestly): the BRDF depends on the
Bragg offset ``beta - beta0`` only through its length d and the sign of its
component along the specular azimuth, as the beta-centred models do: a direction
maps to the in-plane angle with ``sin(theta_r) = sin(theta_i) +/- d`` (clamped to
+-90 deg). In the plane of incidence this is exact; out of plane it is the isotropic
(K-correlation-like) extension, wrong for strongly anisotropic or off-specular lobes.
Not reciprocal in general.

Sampling: an even mixture of the cosine-weighted hemisphere and a radial lobe about
beta0 (PHYSICS §3 proposal, slope 2) whose width is the narrowest half-width at half
maximum of the table's rows in beta; ``u[:, 1] < 1/2`` picks the cosine half (rescaled).
Weight ``f cos / (pdf_cos / 2 + pdf_lobe / 2)``: unbiased, and a narrow specular peak in
the table is sampled where it is.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Optional

import numpy as np

from materials.base import MaterialError, Sample, bragg_offset, check_polarization
from materials.flags import ComponentFlags
from materials.registry import register
from materials.sampling import (
    cosine_hemisphere_pdf,
    direction_uniforms,
    lobe_direction,
    lobe_pdf,
    sample_cosine_hemisphere,
)


def _axis(name, values, lo, hi):
    try:
        arr = np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        raise MaterialError(f"tabulated: {name!r} must be a list of numbers") from None
    if arr.ndim != 1 or arr.size < 1:
        raise MaterialError(f"tabulated: {name!r} must be a non-empty list of numbers")
    if not np.all(np.isfinite(arr)) or np.any(arr < lo) or np.any(arr > hi):
        raise MaterialError(f"tabulated: {name!r} values must lie in [{lo}, {hi}]")
    if np.any(np.diff(arr) <= 0):
        raise MaterialError(f"tabulated: {name!r} must be strictly increasing")
    return tuple(float(v) for v in arr)


def _table(name, values, shape):
    if values is None:
        return None
    try:
        arr = np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        raise MaterialError(f"tabulated: {name!r} must be a list of lists of numbers") from None
    if arr.shape != shape:
        raise MaterialError(f"tabulated: {name!r} has shape {arr.shape}, expected {shape} (theta_i x theta_r)")
    if not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise MaterialError(f"tabulated: {name!r} values must be finite and >= 0")
    return tuple(tuple(float(v) for v in row) for row in arr)


class _Bilinear:
    """Bilinear interpolation on a rectilinear grid, edge values held; log10 when positive."""

    def __init__(self, x, y, z):
        self.x = np.asarray(x, float)
        self.y = np.asarray(y, float)
        z = np.asarray(z, float)
        self.log = bool(np.all(z > 0))
        self.z = np.log10(z) if self.log else z

    @staticmethod
    def _locate(axis, q):
        if axis.size == 1:
            return np.zeros(q.shape, int), np.zeros(q.shape)
        q = np.clip(q, axis[0], axis[-1])
        j = np.clip(np.searchsorted(axis, q, side="right") - 1, 0, axis.size - 2)
        t = (q - axis[j]) / (axis[j + 1] - axis[j])
        return j, t

    def __call__(self, xq, yq):
        i, s = self._locate(self.x, xq)
        j, t = self._locate(self.y, yq)
        i1 = np.minimum(i + 1, self.x.size - 1)
        j1 = np.minimum(j + 1, self.y.size - 1)
        z = self.z
        v = (1 - s) * ((1 - t) * z[i, j] + t * z[i, j1]) + s * ((1 - t) * z[i1, j] + t * z[i1, j1])
        return 10.0**v if self.log else v


@register("tabulated")
@dataclass(frozen=True)
class Tabulated:
    """In-plane BRDF table vs (theta_i, signed theta_r), isotropic about beta0 out of plane."""

    theta_i_deg: tuple
    theta_r_deg: tuple
    brdf_per_sr: Optional[tuple] = None
    brdf_s_per_sr: Optional[tuple] = None
    brdf_p_per_sr: Optional[tuple] = None

    flags = ComponentFlags.GLOSSY
    reciprocal = False

    def __post_init__(self):
        ti = _axis("theta_i_deg", self.theta_i_deg, 0.0, 89.999999)
        tr = _axis("theta_r_deg", self.theta_r_deg, -90.0, 90.0)
        shape = (len(ti), len(tr))
        object.__setattr__(self, "theta_i_deg", ti)
        object.__setattr__(self, "theta_r_deg", tr)
        for key in ("brdf_per_sr", "brdf_s_per_sr", "brdf_p_per_sr"):
            object.__setattr__(self, key, _table(key, getattr(self, key), shape))
        if (self.brdf_s_per_sr is None) != (self.brdf_p_per_sr is None):
            raise MaterialError("tabulated: give both 'brdf_s_per_sr' and 'brdf_p_per_sr' or neither")
        if self.brdf_per_sr is None and self.brdf_s_per_sr is None:
            raise MaterialError("tabulated: needs 'brdf_per_sr' (or both 'brdf_s_per_sr' and 'brdf_p_per_sr')")

    @classmethod
    def example(cls) -> "Tabulated":
        """A table of 0.01/pi + a beta-centred lobe, 10..80 deg incidence, 1-deg viewing steps."""
        ti = np.arange(0.0, 90.0, 10.0)
        tr = np.linspace(-89.0, 89.0, 179)
        d = np.sin(np.deg2rad(tr))[None, :] - np.sin(np.deg2rad(ti))[:, None]
        f = 0.01 / np.pi + 0.05 / (1.0 + (d / 0.05) ** 2) ** 1.2
        return cls(theta_i_deg=tuple(ti), theta_r_deg=tuple(tr), brdf_per_sr=tuple(map(tuple, f)))

    @cached_property
    def _interpolators(self) -> dict:
        out = {}
        ti, tr = np.deg2rad(self.theta_i_deg), np.deg2rad(self.theta_r_deg)
        if self.brdf_s_per_sr is not None:
            out["s"] = _Bilinear(ti, tr, self.brdf_s_per_sr)
            out["p"] = _Bilinear(ti, tr, self.brdf_p_per_sr)
        if self.brdf_per_sr is not None:
            base = _Bilinear(ti, tr, self.brdf_per_sr)
            out["u"] = base
            out.setdefault("s", base)
            out.setdefault("p", base)
        return out

    def check_nodes_deg(self) -> np.ndarray:
        """Incidences the energy check adds to its 1-deg grid: the table's nodes and their midpoints."""
        ti = np.asarray(self.theta_i_deg)
        return np.unique(np.concatenate([ti, 0.5 * (ti[1:] + ti[:-1])]))

    def in_plane_equivalent(self, wi, wo) -> tuple[np.ndarray, np.ndarray]:
        """(theta_i, signed theta_r) radians of the in-plane point with the same |beta - beta0|."""
        wi = np.asarray(wi, float)
        wo = np.asarray(wo, float)
        sin_i = np.hypot(wi[:, 0], wi[:, 1])
        theta_i = np.arctan2(sin_i, wi[:, 2])
        d = bragg_offset(wi, wo)
        dist = np.hypot(d[:, 0], d[:, 1])
        # sign of the offset along the specular azimuth t = -wi_xy / |wi_xy| (x at normal incidence)
        along = np.where(sin_i > 1e-15, -(d[:, 0] * wi[:, 0] + d[:, 1] * wi[:, 1]) / np.maximum(sin_i, 1e-300), d[:, 0])
        sign = np.where(along >= 0, 1.0, -1.0)
        theta_r = np.arcsin(np.clip(sin_i + sign * dist, -1.0, 1.0))
        return theta_i, theta_r

    def brdf(self, wi, wo, polarization: str = "u") -> np.ndarray:
        """Interpolated BRDF in 1/sr (no cos), (n,)."""
        check_polarization(polarization)
        wi = np.asarray(wi, float)
        wo = np.asarray(wo, float)
        above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        theta_i, theta_r = self.in_plane_equivalent(wi, wo)
        interp = self._interpolators
        if polarization == "u" and self.brdf_per_sr is None:
            f = 0.5 * (interp["s"](theta_i, theta_r) + interp["p"](theta_i, theta_r))
        else:
            f = interp[polarization](theta_i, theta_r)
        return np.where(above, f, 0.0)

    @cached_property
    def proposal_width(self) -> float:
        """Narrowest half-width at half maximum of the table rows, in beta (>= 1e-4)."""
        beta_r = np.sin(np.deg2rad(self.theta_r_deg))
        widths = []
        for key in ("brdf_per_sr", "brdf_s_per_sr", "brdf_p_per_sr"):
            table = getattr(self, key)
            if table is None:
                continue
            for row in np.asarray(table, float):
                if row.max() <= 0:
                    continue
                above = np.nonzero(row >= 0.5 * row.max())[0]
                widths.append(0.5 * (beta_r[above[-1]] - beta_r[above[0]]))
        if not widths:
            return 1.0
        return float(np.clip(min(widths), 1e-4, 1.0))

    def sample_direction(self, wi, u) -> np.ndarray:
        """The directions ``sample`` would draw, without weights (used by composites)."""
        wi = np.asarray(wi, float)
        u2 = direction_uniforms(u)
        cos_half = u2[:, 0] < 0.5
        v = u2.copy()
        v[:, 0] = np.where(cos_half, 2.0 * u2[:, 0], 2.0 * u2[:, 0] - 1.0)
        wo = lobe_direction(wi, v, self.proposal_width, 2.0)
        if np.any(cos_half):
            wo[cos_half] = sample_cosine_hemisphere(v[cos_half])
        return wo

    def sample(self, wi, u, polarization: str = "u") -> Sample:
        """Cosine / lobe mixture draw, weight f cos / pdf (0 below the horizon)."""
        check_polarization(polarization)
        wi = np.asarray(wi, float)
        wo = self.sample_direction(wi, u)
        pdf = self.pdf(wi, wo, polarization)
        above = (wo[:, 2] > 0) & (pdf > 0)
        f = self.brdf(wi, wo, polarization)
        weight = np.where(above, f * wo[:, 2] / np.where(above, pdf, 1.0), 0.0)
        return Sample(wo=wo, weight=weight, pdf_per_sr=np.where(above, pdf, 0.0))

    def pdf(self, wi, wo, polarization: str = "u") -> np.ndarray:
        """Mixture density per sr: half cosine, half lobe about beta0."""
        wi = np.asarray(wi, float)
        wo = np.asarray(wo, float)
        cos_part = np.where(wi[:, 2] > 0, cosine_hemisphere_pdf(wo[:, 2]), 0.0)
        return 0.5 * cos_part + 0.5 * lobe_pdf(wi, wo, self.proposal_width, 2.0)

    def to_dict(self) -> dict:
        out = {"type": "tabulated", "theta_i_deg": list(self.theta_i_deg), "theta_r_deg": list(self.theta_r_deg)}
        for key in ("brdf_per_sr", "brdf_s_per_sr", "brdf_p_per_sr"):
            value = getattr(self, key)
            if value is not None:
                out[key] = [list(row) for row in value]
        return out
