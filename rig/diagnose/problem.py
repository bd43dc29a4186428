"""A scan prepared for diagnosis (arrays, usable points, noise model, hold-out, cached rig)
and its least-squares fit through the rig's forward model.

Usable points: ``brdf_per_sr > 2 x standard error`` (the standard error is
``brdf_std_per_sr / sqrt(n_repeats)``; a point without a std only needs ``brdf_per_sr > 0``):
every gap and fit uses only these (the "above its own noise" rule). The relative error of the
mean is smoothed by a straight line in (log10 BRDF, log relative error) through the scan's own
std values, because a std from 3 readings is itself uncertain to ~50 %; residuals are
``log10(measured / simulated) / sigma_log10``. A file without std values gets 5 %.

Hold-out (default): the middle incidence angle (index (n-1)//2 of the sorted list) and the
highest one; with one or two angles, the highest is held out unless that leaves no training data.
"""
from __future__ import annotations

import math
import uuid

import numpy as np
from scipy.optimize import least_squares

from materials.scan import Scan
from rig.diagnose.fast_material import NodeCache
from rig.diagnose.params import Fit, Model, effect_specs, material_specs
from rig.diagnose.regions import classify_regions
from rig.forward import compose
from rig.instrument import RigConfig

#: Relative error assumed when a scan has no usable std column.
DEFAULT_RELATIVE_STD = 0.05
#: Floor on sigma_log10 (model/quadrature error, ~0.5 %).
SIGMA_FLOOR_DEX = 0.002


class DiagnoseError(ValueError):
    """The scan cannot be diagnosed (too few usable points, bad hold-out, unknown effect)."""


class Problem:
    """A scan prepared for diagnosis: arrays in radians, masks, noise model, cached rig."""

    def __init__(self, scan: Scan, holdout_theta_i_deg=None, config: RigConfig | None = None):
        self.scan = scan
        self.config = config if config is not None else RigConfig.from_metadata(
            scan.metadata, where=str(scan.path) if scan.path else "scan metadata")
        self.wavelength_nm = float(np.nanmedian(scan.wavelength_nm))
        self.theta_i = scan.theta_i
        self.theta_r = scan.theta_r
        self.phi_r = scan.phi_r
        self.pol = np.asarray(scan.polarization, str)
        self.theta_i_deg = np.asarray(scan.theta_i_deg, float)
        self.signed_tr_deg = scan.signed_theta_r_deg
        self.region = classify_regions(self.theta_i_deg, self.signed_tr_deg)
        y = np.asarray(scan.brdf_per_sr, float)
        std = np.asarray(scan.brdf_std_per_sr, float)
        nrep = np.maximum(np.asarray(scan.n_repeats, float), 1.0)
        sem = std / np.sqrt(nrep)
        with np.errstate(invalid="ignore"):
            usable = np.isfinite(y) & (y > 0) & (~np.isfinite(sem) | (y > 2.0 * sem))
        self.y = y
        self.sem = sem
        self.usable = usable
        self.log_y = np.where(usable, np.log10(np.where(usable, y, 1.0)), np.nan)
        self.sigma_log = self._noise_model(y, sem, usable)
        has_sem = usable & np.isfinite(sem) & (sem > 0)
        self.noise_dex = np.where(has_sem, sem / (np.where(usable, y, 1.0) * math.log(10)), np.nan)

        angles = np.unique(self.theta_i_deg)
        if holdout_theta_i_deg is None:
            hold = default_holdout(angles)
        else:
            hold = []
            for h in holdout_theta_i_deg:
                match = angles[np.abs(angles - h) < 1e-6]
                if match.size == 0:
                    raise DiagnoseError(f"--holdout-theta-i {h:g}: no such incidence angle in the scan "
                                        f"(it has {', '.join(f'{a:g}' for a in angles)})")
                hold.append(float(match[0]))
        self.heldout_deg = sorted(set(hold))
        self.heldout = np.isin(self.theta_i_deg, self.heldout_deg)
        self.train = ~self.heldout
        self.train_idx = np.flatnonzero(self.train & usable)
        self.held_idx = np.flatnonzero(self.heldout & usable)
        if self.train_idx.size < 8:
            raise DiagnoseError(f"only {self.train_idx.size} usable training points; need at least 8")
        self.cache = NodeCache()
        # contiguous copies so cache keys are stable
        self._sub: dict[bytes, tuple] = {}  # index bytes -> the arrays at those indices
        # identifies this problem in worker processes (rig.diagnose.tasks keeps one copy per token)
        self.token = uuid.uuid4().hex

    def __getstate__(self):
        """Pickled without its caches (they are rebuilt on first use in the other process)."""
        state = dict(self.__dict__)
        state["cache"] = None
        state["_sub"] = {}
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self.cache = NodeCache()

    @staticmethod
    def _noise_model(y, sem, usable):
        """sigma of log10(mean): a line in (log10 y, log relative sem) through the scan's own stds."""
        ok = usable & np.isfinite(sem) & (sem > 0)
        ly = np.log10(np.where(usable, y, 1.0))
        if ok.sum() >= 5:
            rel = np.log(sem[ok] / y[ok])
            a = np.polyfit(ly[ok], rel, 1) if np.ptp(ly[ok]) > 0.5 else np.array([0.0, np.mean(rel)])
            # a line from noisy 3-reading stds; stds are chi-distributed so their log is biased low
            # by E[log chi_2 / sqrt 2] ~ -0.29 for 3 readings; correct by matching the mean variance
            pred = np.exp(np.polyval(a, ly))
            scale = math.sqrt(np.mean((sem[ok] / y[ok]) ** 2) / np.mean(pred[ok] ** 2))
            rel_sem = pred * scale
        else:
            rel_sem = np.full(y.shape, DEFAULT_RELATIVE_STD)
        return np.hypot(rel_sem / math.log(10), SIGMA_FLOOR_DEX)

    def arrays(self, idx):
        key = idx.tobytes()
        sub = self._sub.get(key)
        if sub is None:
            sub = tuple(np.ascontiguousarray(a[idx]) for a in (self.theta_i, self.theta_r, self.phi_r, self.pol))
            self._sub[key] = sub
        return sub

    def predict(self, model: Model, idx=None) -> np.ndarray:
        idx = np.arange(self.y.size) if idx is None else idx
        ti, tr, pr, pol = self.arrays(idx)
        forward = compose(model.effect_objects(), base=self.cache)
        return forward(ti, tr, pr, pol, self.config, model.material(self.wavelength_nm))

    def log_residual(self, model: Model, idx) -> np.ndarray:
        """log10(measured / simulated) on points idx (usable only)."""
        sim = self.predict(model, idx)
        return self.log_y[idx] - np.log10(np.maximum(sim, 1e-300))

    def gap(self, model: Model, idx) -> float | None:
        if idx.size == 0:
            return None
        r = self.log_residual(model, idx)
        return float(np.sqrt(np.mean(r * r)))

    def chi2(self, model: Model, idx) -> float:
        """Sum of squared normalised log residuals on points idx (0 when idx is empty)."""
        if idx.size == 0:
            return 0.0
        r = self.log_residual(model, idx) / self.sigma_log[idx]
        return float(np.sum(r * r))

    def noise_level(self, idx) -> float | None:
        v = self.noise_dex[idx]
        v = v[np.isfinite(v)]
        return float(np.sqrt(np.mean(v * v))) if v.size else None

    # ------------------------------------------------------------------ fitting
    def fit(self, model: Model, free=None, max_nfev=60) -> Fit:
        """Least-squares fit of ``model`` on the training points; ``free``: which (owner, name)
        to vary (default all). Returns a Fit whose model holds the fitted values."""
        specs = model.specs()
        if free is not None:
            specs = [s for s in specs if (s.owner, s.name) in free]
        idx = self.train_idx
        sig = self.sigma_log[idx]
        x0 = np.array([np.clip(s.to_x(model.values[(s.owner, s.name)]), *s.bounds_x) for s in specs])
        lo = np.array([s.bounds_x[0] for s in specs])
        hi = np.array([s.bounds_x[1] for s in specs])
        x0 = np.clip(x0, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))

        def with_x(x):
            vals = dict(model.values)
            for s, xi in zip(specs, x):
                vals[(s.owner, s.name)] = s.from_x(xi)
            return Model(model.n_lobes, vals, model.effects)

        def fun(x):
            r = self.log_residual(with_x(x), idx) / sig
            return np.where(np.isfinite(r), r, 1e3)

        res = least_squares(fun, x0, bounds=(lo, hi), method="trf", x_scale="jac", diff_step=1e-3,
                            max_nfev=max_nfev, xtol=1e-6, ftol=1e-6)
        fitted = with_x(res.x)
        chi2 = float(np.sum(res.fun**2))
        k = len(material_specs(model.n_lobes)) + sum(len(effect_specs(e)) for e in model.effects)
        return Fit(fitted, chi2, k, idx.size, bool(res.success), int(res.nfev))


def default_holdout(angles) -> list:
    """Middle (index (n-1)//2) and highest incidence angle; fewer when the scan has fewer."""
    a = sorted(float(x) for x in angles)
    if len(a) >= 3:
        return sorted({a[(len(a) - 1) // 2], a[-1]})
    if len(a) == 2:
        return [a[-1]]
    return []
