"""Sum of BRDF components (seed paper Eq. 2: Lambertian + one or two K-correlation lobes).

``f = sum_k f_k``. Sampling is one-sample multiple importance sampling (PHYSICS §3):
component k is chosen with probability ``p_k(theta_i)`` proportional to its
directional-hemispherical reflectance (tabulated on a theta_i grid per polarization
and interpolated; any p_k > 0 keeps the estimator unbiased, so a coarse table is
enough), and the draw carries ``weight = f_total cos / sum_k p_k pdf_k``.
``u[:, 0]`` chooses the component, ``u[:, 1:]`` the direction (materials.base).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from materials.albedo import directional_hemispherical_reflectance
from materials.base import MaterialError, PairGeometry, Sample, check_polarization
from materials.kcorrelation import KCorrelation
from materials.lambertian import Lambertian
from materials.sampling import lazy_njit

_TABLE_THETA = np.deg2rad(np.linspace(0.0, 90.0, 37))
_FLOOR = 1e-3  # mixing floor: every component keeps >= 0.1 % / K of the draws


@dataclass(frozen=True, eq=False)
class Composite:
    """Sum of components; each provides the Brdf protocol (materials.base)."""

    components: tuple

    def __post_init__(self):
        comps = tuple(self.components)
        if not comps:
            raise MaterialError("composite: needs at least one component")
        object.__setattr__(self, "components", comps)

    @property
    def reciprocal(self) -> bool:
        return all(getattr(c, "reciprocal", False) for c in self.components)

    @classmethod
    def example(cls) -> "Composite":
        """Seed paper Eq. 2 three-component form: diffuse + narrow specular + glossy lobe."""
        return cls(
            (
                Lambertian(rd=0.02),
                KCorrelation(sigma_nm=2.0, lc_um=40.0, s=2.4, n=1.55, wavelength_nm=532.0),
                KCorrelation(sigma_nm=20.0, lc_um=3.0, s=3.0, n=1.55, weight=0.5, wavelength_nm=532.0),
            )
        )

    # ------------------------------------------------------------ selection probabilities

    @cached_property
    def _albedo_tables(self) -> dict:
        return {}

    def _table(self, polarization: str) -> np.ndarray:
        tables = self._albedo_tables
        if polarization not in tables:
            rows = [
                directional_hemispherical_reflectance(c, _TABLE_THETA[:-1], polarization, 40, 64)
                for c in self.components
            ]
            arr = np.array(rows)  # (K, T-1)
            arr = np.concatenate([arr, arr[:, -1:]], axis=1)  # hold the 89.x value at 90 deg
            tables[polarization] = np.maximum(arr, 0.0)
        return tables[polarization]

    def selection_probabilities(self, theta_i, polarization: str = "u") -> np.ndarray:
        """p_k(theta_i), shape (n, K): proportional to each component's albedo, with a floor. One
        compiled pass (:func:`_selection_loop`) with :meth:`selection_probabilities_numpy`'s operations
        in its order (the same bits); NaN angles and K >= 8 (numpy's sum turns pairwise) take numpy."""
        table = self._table(polarization)
        th = np.atleast_1d(np.asarray(theta_i, float))
        k = len(self.components)
        if k >= 8 or th.ndim != 1 or np.isnan(th).any():
            return self.selection_probabilities_numpy(theta_i, polarization)
        p = np.empty((len(th), k))
        lazy_njit(_selection_loop, "numpy")(th, _TABLE_THETA, np.ascontiguousarray(table), np.pi / 2, 1.0 / k,
                                            1.0 - _FLOOR, _FLOOR / k, p)
        return p

    def selection_probabilities_numpy(self, theta_i, polarization: str = "u") -> np.ndarray:
        """:meth:`selection_probabilities` in vectorised numpy (the reference it is tested against)."""
        table = self._table(polarization)
        th = np.clip(np.atleast_1d(np.asarray(theta_i, float)), 0.0, np.pi / 2)
        alb = np.stack([np.interp(th, _TABLE_THETA, row) for row in table], axis=-1)
        k = len(self.components)
        total = alb.sum(axis=1, keepdims=True)
        safe = np.where(total > 0, total, 1.0)
        p = np.where(total > 0, alb / safe, 1.0 / k)
        p = (1.0 - _FLOOR) * p + _FLOOR / k
        return p

    # ------------------------------------------------------------ protocol

    def brdf(self, wi, wo, polarization: str = "u", pair=None) -> np.ndarray:
        """Sum of the components' BRDFs, 1/sr (no cos). ``pair``: the (wi, wo)
        :class:`materials.base.PairGeometry` to share (made here when None)."""
        check_polarization(polarization)
        g = PairGeometry(wi, wo) if pair is None else pair
        out = _brdf(self.components[0], g, polarization)
        for c in self.components[1:]:
            out = out + _brdf(c, g, polarization)
        return out

    def pdf(self, wi, wo, polarization: str = "u", pair=None) -> np.ndarray:
        """Mixture density sum_k p_k(theta_i) pdf_k, per sr (``pair`` as for :meth:`brdf`)."""
        check_polarization(polarization)
        g = PairGeometry(wi, wo) if pair is None else pair
        if len(self.components) == 1:  # p_0 = 1: the component's own density
            return _pdf(self.components[0], g, polarization)
        wi = g.wi
        p = self.selection_probabilities(np.arccos(np.clip(wi[:, 2], -1, 1)), polarization)
        out = np.zeros(len(wi))
        for k, c in enumerate(self.components):
            out += p[:, k] * _pdf(c, g, polarization)
        return out

    def brdf_pdf(self, wi, wo, polarization: str = "u") -> tuple[np.ndarray, np.ndarray]:
        """``(brdf, pdf)`` of the same pairs, the lobes' shared quantities made once (the same bits as
        the two calls)."""
        g = PairGeometry(wi, wo)
        return self.brdf(wi, wo, polarization, g), self.pdf(wi, wo, polarization, g)

    def sample(self, wi, u, polarization: str = "u") -> Sample:
        """One-sample MIS: u[:, 0] picks component k, u[:, 1:] its direction."""
        check_polarization(polarization)
        wi = np.asarray(wi, float)
        u = np.asarray(u, float)
        if u.ndim != 2 or u.shape[1] != 3:
            raise ValueError(f"composite sampling needs uniforms of shape (n, 3), got {u.shape}")
        if len(self.components) == 1:  # p_0 = 1: the component's own draw (same uniforms u[:, 1:])
            return self.components[0].sample(wi, u, polarization)
        n = len(wi)
        p = self.selection_probabilities(np.arccos(np.clip(wi[:, 2], -1, 1)), polarization)
        cdf = np.cumsum(p, axis=1)
        choice = np.minimum((u[:, :1] >= cdf).sum(axis=1), len(self.components) - 1)
        wo = np.zeros((n, 3))
        for k, c in enumerate(self.components):
            m = np.flatnonzero(choice == k)
            if len(m):
                # components read u[:, 1:]; sample_direction skips weights we recompute below
                draw = getattr(c, "sample_direction", None)
                wi_m, u_m = wi.take(m, axis=0), u.take(m, axis=0)  # wi[m], u[m] (np.take: faster on rows)
                wo[m] = draw(wi_m, u_m) if draw is not None else c.sample(wi_m, u_m, polarization).wo
        above = (wo[:, 2] > 0) & (wi[:, 2] > 0)
        g = PairGeometry(wi, wo)
        mix = np.zeros(n)
        for k, c in enumerate(self.components):
            mix += p[:, k] * _pdf(c, g, polarization)
        f = self.brdf(wi, wo, polarization, g)
        good = above & (mix > 0)
        weight = np.where(good, f * wo[:, 2] / np.where(good, mix, 1.0), 0.0)
        return Sample(wo=wo, weight=weight, pdf_per_sr=np.where(good, mix, 0.0))

    def to_dict(self) -> dict:
        return {"components": [c.to_dict() for c in self.components]}


def _brdf(c, g, polarization):
    """Component ``c``'s BRDF on the pairs of ``g``, sharing them when ``c`` takes a PairGeometry."""
    if getattr(c, "pair_geometry", False):
        return c.brdf(g.wi, g.wo, polarization, pair=g)
    return c.brdf(g.wi, g.wo, polarization)


def _pdf(c, g, polarization):
    if getattr(c, "pair_geometry", False):
        return c.pdf(g.wi, g.wo, polarization, pair=g)
    return c.pdf(g.wi, g.wo, polarization)


def _selection_loop(theta, xp, table, top, uniform, keep, floor, out):
    """:meth:`Composite.selection_probabilities_numpy` row by row: ``np.clip``, ``np.interp``'s
    interval and formula (``slope (x - xp_j) + fp_j``, the other end's form where that is NaN, the
    last node exactly at the end), the row sum left to right, the floor."""
    n_k, last = table.shape[0], len(xp) - 1
    step_inv = last / (xp[last] - xp[0])
    slopes = np.empty((n_k, last))  # as np.interp forms them
    for c in range(n_k):
        for i in range(last):
            slopes[c, i] = (table[c, i + 1] - table[c, i]) / (xp[i + 1] - xp[i])
    for r in range(len(theta)):
        x = theta[r]
        x = 0.0 if x < 0.0 else (top if x > top else x)
        if x >= xp[last]:
            j = last
        else:  # the node interval xp[j] <= x < xp[j + 1], from the guess of an even grid
            j = min(max(int(x * step_inv), 0), last - 1)
            while j > 0 and xp[j] > x:
                j -= 1
            while j < last - 1 and xp[j + 1] <= x:
                j += 1
        total = 0.0
        for c in range(n_k):
            if j == last:
                a = table[c, last]
            else:
                slope = slopes[c, j]
                a = slope * (x - xp[j]) + table[c, j]
                if a != a:  # NaN
                    a = slope * (x - xp[j + 1]) + table[c, j + 1]
                    if a != a and table[c, j] == table[c, j + 1]:
                        a = table[c, j]
            out[r, c] = a
            total = a if c == 0 else total + a
        for c in range(n_k):
            p = out[r, c] / total if total > 0 else uniform
            out[r, c] = keep * p + floor
