"""Sim-to-real diagnosis: fit the sample through the rig model, then explain the rest.

Method (Kennedy & O'Hagan-style calibration with a discrepancy made of *named* effect
terms; PHYSICS §4 "diagnosis practice"):

1. **Data and noise.** Points with ``brdf_per_sr > 2 x standard error`` (the standard
   error is ``brdf_std_per_sr / sqrt(n_repeats)``; a point without a std only needs
   ``brdf_per_sr > 0``) are *usable*: every gap and fit uses only these (the "above its
   own noise" rule). The relative error of the mean is smoothed by a straight line in
   (log10 BRDF, log relative error) through the scan's own std values, because a std
   from 3 readings is itself uncertain to ~50 %; residuals are
   ``log10(measured / simulated) / sigma_log10``. A file without std values gets 5 %.
2. **Hold-out.** Default: the middle incidence angle (index (n-1)//2 of the sorted list)
   and the highest one; with one or two angles, the highest is held out unless that
   leaves no training data. ``--holdout-theta-i`` overrides.
3. **Baseline.** Lambertian + one or two K-correlation lobes (shared refractive index n,
   s and p fitted jointly through :mod:`rig.forward` on the nominal rig) on the training
   angles; one or two lobes chosen by BIC.
4. **Candidates.** Every catalogue effect (or ``--effects``) is fitted *jointly with the
   material* (warm start from the baseline, a few starts for the effect's parameters),
   and scored by ``delta_bic`` (BIC = chi^2 + k ln N on the training points) and by
   the held-out gap before and after.
5. **Forward selection.** The best candidate (lowest BIC) is kept if it lowers BIC by more
   than :data:`BIC_THRESHOLD` *and* improves the prediction of the held-out angles: their
   chi^2 falls by more than :data:`HELDOUT_CHI2_GAIN` and their gap falls; repeat with the
   rest on top (only the best :data:`MAX_RETRIED` candidates that helped alone are
   retried). Candidates that helped alone but add nothing once another was selected are
   reported as *confounded* with it (e.g. an offset and the slit width both act in
   the specular core). An effect whose fitted parameter sits at a bound of its plausible
   range (``at_bound`` in the JSON) is never selected: the residual is larger than any
   plausible instrument error of that kind, which usually means the material model fails.
   After each selection, the candidates that did not help alone are screened again on top
   of the new model (effect parameters only, material fixed) and join the pool when they now
   lower chi^2 by more than the BIC penalty: a smaller effect can be masked by a bigger one
   (a 1 deg tilt under 7 % polarization leakage fits to zero tilt alone).
   Finally a backward pass refits without each selected effect in turn and drops it when
   removing it costs less than :data:`BIC_THRESHOLD` in BIC or less than
   :data:`HELDOUT_CHI2_GAIN` in held-out chi^2 (``dropped_effects``), and the final model is
   refitted from fresh material starts with the effects held, then jointly
   (:func:`refit_fresh_material`): the baseline material has bent to imitate the effects and
   can hold the joint fit in a local minimum (a 1 deg tilt on the z302_sample_a preset
   ended at 0.89 deg and 1.8x the noise level without it, at 1.00 deg and 1.03x with it).
6. **Regions.** ``specular_core`` (|theta_r - theta_i| <= 0.5 deg in the plane),
   ``shoulder`` (0.5..5 deg), ``wing`` (beyond), and where present ``grazing`` (viewing
   beyond 75 deg, outside core and shoulder) and ``near_retro`` (backscatter side within
   10 deg of the incident beam). One entry per region, incidence angle and polarization.

The *noise level* is the gap a perfect model would leave: the RMS over the usable points
of the measured standard error in dex, ``std / (sqrt(n) brdf ln 10)``.
"""
from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, field
from functools import lru_cache
from types import SimpleNamespace

import numpy as np
from scipy.optimize import least_squares

from materials.kcorrelation import KCorrelation
from materials.scan import Scan
from rig.effects import CATALOGUE, build_effect, effect_types
from rig.forward import compose, node_groups
from rig.instrument import RigConfig
from rig.node_integrals import cached_integral

GAP_METRIC = "rms_log10"
#: BIC must drop by more than this to keep an effect ("very strong" evidence, Kass & Raftery 1995).
BIC_THRESHOLD = 10.0
#: ... and the held-out chi^2 (predictive fit on incidences the fit never saw) must fall by
#: more than this, with the held-out gap falling too.
HELDOUT_CHI2_GAIN = 10.0
#: Relative error assumed when a scan has no usable std column.
DEFAULT_RELATIVE_STD = 0.05
#: Floor on sigma_log10 (model/quadrature error, ~0.5 %).
SIGMA_FLOOR_DEX = 0.002
#: Forward selection retries at most this many of the candidates that helped alone (best first).
MAX_RETRIED = 6
CORE_DEG, SHOULDER_DEG, GRAZING_DEG, RETRO_DEG = 0.5, 5.0, 75.0, 10.0
REGION_ORDER = ("specular_core", "shoulder", "wing", "grazing", "near_retro")


class DiagnoseError(ValueError):
    """The scan cannot be diagnosed (too few usable points, bad hold-out, unknown effect)."""


# ----------------------------------------------------------------------------- regions

def classify_regions(theta_i_deg, signed_theta_r_deg) -> np.ndarray:
    """Region name per point (see module doc)."""
    ti = np.asarray(theta_i_deg, float)
    tr = np.asarray(signed_theta_r_deg, float)
    off = np.abs(tr - ti)
    out = np.full(ti.shape, "wing", dtype=object)
    out[(np.abs(tr) > GRAZING_DEG)] = "grazing"
    out[(tr < 0) & (np.abs(tr + ti) <= RETRO_DEG)] = "near_retro"
    out[off <= SHOULDER_DEG] = "shoulder"
    out[off <= CORE_DEG] = "specular_core"
    return out.astype(str)


# ----------------------------------------------------------------------------- fast material

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


# ----------------------------------------------------------------------------- parameters

@dataclass(frozen=True)
class ParamSpec:
    """One optimiser variable: which object it belongs to, its name, bounds and scale."""

    owner: str  # "material" or an effect name
    name: str
    lo: float
    hi: float
    scale: str  # "lin" | "log"

    def to_x(self, value):
        return math.log10(value) if self.scale == "log" else float(value)

    def from_x(self, x):
        return 10.0**x if self.scale == "log" else float(x)

    @property
    def bounds_x(self):
        return (self.to_x(self.lo), self.to_x(self.hi))


def material_specs(n_lobes: int):
    specs = [ParamSpec("material", "rd", 1e-6, 0.99, "log")]
    for k in range(n_lobes):
        specs += [ParamSpec("material", f"sigma{k}_nm", 1e-3, 300.0, "log"),
                  ParamSpec("material", f"lc{k}_um", 0.05, 1000.0, "log"),
                  ParamSpec("material", f"s{k}", 1.0, 6.0, "lin")]
    specs.append(ParamSpec("material", "n", 1.05, 3.0, "lin"))
    return specs


def effect_specs(name: str):
    cls = effect_types()[name]
    return [ParamSpec(name, p, lo, hi, scale) for p, (lo, hi, scale, _) in cls.fit_space.items()]


@dataclass
class Model:
    """A point in model space: material values and effect parameter values."""

    n_lobes: int
    values: dict  # (owner, name) -> value
    effects: tuple = ()  # effect names, in the order added

    def material(self, wavelength_nm) -> FitMaterial:
        v = self.values
        lobes = tuple((v[("material", f"sigma{k}_nm")], v[("material", f"lc{k}_um")], v[("material", f"s{k}")])
                      for k in range(self.n_lobes))
        return FitMaterial(v[("material", "rd")], lobes, v[("material", "n")], wavelength_nm)

    def effect_objects(self):
        out = []
        for name in self.effects:
            params = {p: self.values[(name, p)] for p in effect_types()[name].fit_space}
            out.append(build_effect(name, **params))
        return out

    def effect_params(self, name):
        return {p: self.values[(name, p)] for p in effect_types()[name].fit_space}

    def specs(self):
        s = material_specs(self.n_lobes)
        for name in self.effects:
            s += effect_specs(name)
        return s


@dataclass
class Fit:
    model: Model
    chi2: float
    k: int
    n_points: int
    success: bool
    nfev: int

    @property
    def bic(self) -> float:
        return self.chi2 + self.k * math.log(max(self.n_points, 1))


# ----------------------------------------------------------------------------- the problem

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
        self._sub = {}

    def fork(self) -> "Problem":
        """A shallow copy with its own (empty) caches, for use on another thread."""
        import copy

        twin = copy.copy(self)
        twin.cache = NodeCache()
        twin._sub = {}
        return twin

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


# ----------------------------------------------------------------------------- starts

def _material_starts(problem: Problem, n_lobes: int):
    """A few material starting points from the data."""
    idx = problem.train_idx
    y = problem.y[idx]
    off = np.abs(problem.signed_tr_deg[idx] - problem.theta_i_deg[idx]) > 20
    rd = float(np.clip(np.pi * np.median(y[off]) if off.any() else np.pi * np.min(y), 1e-5, 0.5))
    starts = []
    if n_lobes == 1:
        lobe_sets = [[(5.0, 5.0, 2.5)], [(20.0, 1.0, 3.0)], [(2.0, 30.0, 2.2)]]
    else:
        lobe_sets = [[(2.0, 30.0, 2.5), (20.0, 1.0, 3.0)], [(3.0, 10.0, 2.2), (30.0, 0.5, 3.5)],
                     [(10.0, 300.0, 2.3), (20.0, 3.0, 3.0)]]
    for lobes in lobe_sets:
        vals = {("material", "rd"): rd, ("material", "n"): 1.5}
        for k, (s, l, sl) in enumerate(lobes):
            vals[("material", f"sigma{k}_nm")] = s
            vals[("material", f"lc{k}_um")] = l
            vals[("material", f"s{k}")] = sl
        starts.append(Model(n_lobes, vals))
    return starts


def _rescale_lobes(problem: Problem, model: Model) -> Model:
    """Scale all lobe sigmas so the model's highest training reading matches the data's
    (BRDF ~ sigma^2): a cheap first step that keeps the optimiser out of flat regions."""
    idx = problem.train_idx
    sim = problem.predict(model, idx)
    ratio = float(np.max(problem.y[idx]) / max(np.max(sim), 1e-300))
    vals = dict(model.values)
    for k in range(model.n_lobes):
        vals[("material", f"sigma{k}_nm")] = float(np.clip(vals[("material", f"sigma{k}_nm")] * math.sqrt(ratio), 1e-3, 300))
    return Model(model.n_lobes, vals, model.effects)


def _effect_starts(problem: Problem, name: str):
    """Starting values for an effect's parameters (data-driven where the catalogue says None)."""
    cls = effect_types()[name]
    idx = problem.train_idx
    y = problem.y[idx]
    x = y * np.cos(problem.theta_r[idx])
    combos = [{}]
    for p, (lo, hi, scale, starts) in cls.fit_space.items():
        values = []
        for s in starts:
            if s is not None:
                values.append(s)
            elif name == "stray_background":
                values += [0.3 * float(np.percentile(x, 5)), 0.03 * float(np.percentile(x, 5))]
            elif name == "detector_nonlinearity":
                values += [3.0 * float(np.max(x)), 30.0 * float(np.max(x))]
            elif name == "substrate_reflection":
                values += [1e-4, 3e-3]
            else:
                values.append(0.5 * (lo + hi))
        values = [float(np.clip(v, lo, hi)) for v in values]
        combos = [dict(c, **{p: v}) for c in combos for v in values]
    return combos[:3]


# ----------------------------------------------------------------------------- driver

@dataclass
class Diagnosis:
    """Everything the JSON and the report need."""

    problem: Problem
    baseline: Fit
    candidates: list  # dicts, best first
    selected: list
    final: Fit
    single_fits: dict  # effect name -> Fit alone
    confounded: list
    dropped: list
    timings: dict = field(default_factory=dict)


def _at_bound(model: Model, name: str) -> list:
    """Parameters of effect ``name`` pinned (within 0.1 % of the range) at a bound of the
    catalogue's plausible range: the residual is larger than any plausible instrument error of
    that kind, so the effect is not selected (usually the material model is what fails)."""
    out = []
    for spec in effect_specs(name):
        x = spec.to_x(model.values[(name, spec.name)])
        lo, hi = spec.bounds_x
        if min(x - lo, hi - x) < 1e-3 * (hi - lo):
            out.append(spec.name)
    return out


def _progress(iterable, total, desc, show):
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover
        return iterable
    return tqdm(iterable, total=total, desc=desc, file=sys.stderr, disable=not show, leave=False)


_WORKER_PROBLEM = None  # in a worker process: the Problem it inherited at the fork


def _set_worker_problem(problem):
    global _WORKER_PROBLEM
    _WORKER_PROBLEM = problem


def _in_worker(task):
    fn, args = task
    return fn(_WORKER_PROBLEM, *args)


def _run_parallel(problem: Problem, fn, arglist, workers: int, progress: bool = False, desc: str = "") -> list:
    """``[fn(problem, *args) for args in arglist]`` on ``workers`` forked processes (threads ran
    at ~1.2x on 2 cores: the fit is Python-heavy and holds the GIL). ``fn`` is a module-level
    function; each process inherits ``problem`` (and its caches) at the fork, so concurrent
    diagnoses do not share it. The results, in order, are those of the serial loop."""
    arglist = [tuple(a) for a in arglist]
    if workers <= 1 or len(arglist) <= 1:
        return [fn(problem, *a) for a in _progress(arglist, len(arglist), desc, progress)]
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    # with "fork" the initializer's arguments are inherited, not pickled
    with ProcessPoolExecutor(max_workers=min(workers, len(arglist)), mp_context=multiprocessing.get_context("fork"),
                             initializer=_set_worker_problem, initargs=(problem,)) as pool:
        results = pool.map(_in_worker, [(fn, a) for a in arglist])
        return list(_progress(results, len(arglist), desc, progress))


def _baseline_job(problem: Problem, start: Model, max_nfev: int) -> Fit:
    return problem.fit(_rescale_lobes(problem, start), max_nfev=max_nfev)


def fit_baseline(problem: Problem, workers: int = 1) -> Fit:
    """Material only, one or two lobes, several starts (run on ``workers`` threads); lowest BIC
    wins (first in start order on ties, as a serial loop)."""
    args = [(start, 80 if n_lobes == 1 else 120) for n_lobes in (1, 2) for start in _material_starts(problem, n_lobes)]
    best = None
    for f in _run_parallel(problem, _baseline_job, args, workers):
        if best is None or f.bic < best.bic:
            best = f
    # polish the winner
    polished = problem.fit(best.model, max_nfev=100)
    return polished if polished.bic <= best.bic else best


def _effect_prefits(problem: Problem, base: Fit, name: str) -> Fit:
    """``base`` plus effect ``name`` with only the effect's parameters free (material fixed,
    cheap), from each of the effect's starts; the best."""
    best = None
    for start in _effect_starts(problem, name):
        vals = dict(base.model.values)
        vals.update({(name, p): v for p, v in start.items()})
        model = Model(base.model.n_lobes, vals, base.model.effects + (name,))
        f = problem.fit(model, free={(name, p) for p in start}, max_nfev=12)
        if best is None or f.chi2 < best.chi2:
            best = f
    return best


def fit_with_effect(problem: Problem, base: Fit, name: str, max_nfev=25) -> Fit:
    """``base`` plus effect ``name``: the effect's parameters alone from each start (material
    fixed, cheap), then everything jointly from the best of those."""
    best = _effect_prefits(problem, base, name)
    joint = problem.fit(best.model, max_nfev=max_nfev)
    return joint if joint.chi2 <= best.chi2 else best


def refit_fresh_material(problem: Problem, fit: Fit, workers: int = 1) -> Fit:
    """``fit``'s effects held at their values, the material refitted from the baseline's fresh
    starts (one and two lobes), then everything jointly from the best; the better of that and
    ``fit`` by BIC. The joint fits start from the baseline material, which has already bent
    to imitate the effects (a tilt lowers the peak: the baseline lowers n and widens the lobe)
    and can hold the joint fit in a local minimum."""
    effect_vals = {k: v for k, v in fit.model.values.items() if k[0] != "material"}
    args = [(Model(n_lobes, {**start.values, **effect_vals}, fit.model.effects),)
            for n_lobes in (1, 2) for start in _material_starts(problem, n_lobes)]
    best = fit
    for f in _run_parallel(problem, _fresh_job, args, workers):
        if f.bic < best.bic:
            best = f
    return best


def _fresh_job(problem: Problem, model: Model) -> Fit:
    m = _rescale_lobes(problem, model)
    free = {(s.owner, s.name) for s in material_specs(m.n_lobes)}
    return problem.fit(problem.fit(m, free=free, max_nfev=60).model, max_nfev=40)


def _unmasked(problem: Problem, base: Fit, names, workers: int) -> list:
    """Those of ``names`` whose effect-only fit on top of ``base`` lowers chi^2 by more than the
    BIC threshold plus the effect's parameter penalty (a cheap screen: material fixed)."""
    names = list(names)
    fits = _run_parallel(problem, _effect_prefits, [(base, n) for n in names], workers)
    log_n = math.log(max(problem.train_idx.size, 1))
    return [n for n, f in zip(names, fits)
            if base.chi2 - f.chi2 > BIC_THRESHOLD + len(effect_specs(n)) * log_n and not _at_bound(f.model, n)]


def _fit_many(problem: Problem, base: Fit, names, workers: int, progress: bool, desc: str) -> dict:
    """fit_with_effect for each name, on ``workers`` processes (:func:`_run_parallel`)."""
    names = list(names)
    fits = _run_parallel(problem, fit_with_effect, [(base, n) for n in names], workers, progress, desc)
    return dict(zip(names, fits))


def _without_job(problem: Problem, name: str, model: Model) -> Fit:
    """``model`` refitted without effect ``name`` (the backward pass)."""
    rest = tuple(e for e in model.effects if e != name)
    vals = {k: v for k, v in model.values.items() if k[0] != name}
    return problem.fit(Model(model.n_lobes, vals, rest), max_nfev=25)


def diagnose(scan: Scan, holdout_theta_i_deg=None, effects=None, config: RigConfig | None = None,
             progress: bool = False, workers: int = 2) -> Diagnosis:
    """Fit ``scan`` through the rig model and rank instrument effects (module doc)."""
    names = list(CATALOGUE if not effects else effects)
    for n in names:
        if n not in effect_types():
            raise DiagnoseError(f"--effects: unknown effect {n!r}; known: {', '.join(effect_types())}")
    t0 = time.perf_counter()
    problem = Problem(scan, holdout_theta_i_deg, config)
    baseline = fit_baseline(problem, workers)
    t1 = time.perf_counter()
    held = problem.held_idx
    gap_before = problem.gap(baseline.model, held)

    singles = _fit_many(problem, baseline, names, workers, progress, "candidates")
    t2 = time.perf_counter()

    candidates = []
    for name in names:
        f = singles[name]
        candidates.append({
            "name": name,
            "fitted": {p: float(v) for p, v in f.model.effect_params(name).items()},
            "delta_bic": float(f.bic - baseline.bic),
            "heldout_gap_before": gap_before,
            "heldout_gap_after": problem.gap(f.model, held),
            "train_gap_after": problem.gap(f.model, problem.train_idx),
            "delta_heldout_chi2": problem.chi2(f.model, held) - problem.chi2(baseline.model, held),
            "region": effect_types()[name].region,
            "at_bound": _at_bound(f.model, name),
        })
    candidates.sort(key=lambda c: (c["delta_bic"], c["heldout_gap_after"] if c["heldout_gap_after"] is not None else 0.0))

    # forward selection
    selected, confounded = [], []
    current = baseline
    current_gap = gap_before
    helpful = [c["name"] for c in candidates if c["delta_bic"] < -BIC_THRESHOLD and not c["at_bound"]]
    pool = list(helpful[:MAX_RETRIED])
    round_fits = {n: singles[n] for n in pool}
    while pool:
        ranked = sorted(pool, key=lambda n: round_fits[n].bic)
        chosen = None
        for n in ranked:
            f = round_fits[n]
            dbic = f.bic - current.bic
            gap_after = problem.gap(f.model, held)
            if dbic >= -BIC_THRESHOLD:
                break
            d_held = problem.chi2(f.model, held) - problem.chi2(current.model, held)
            if held.size == 0 or (d_held < -HELDOUT_CHI2_GAIN and gap_after < current_gap):
                chosen = n
                break
        if chosen is None:
            break
        selected.append(chosen)
        current = round_fits[chosen]
        current_gap = problem.gap(current.model, held)
        pool.remove(chosen)
        # an effect masked by a bigger one (its signature appears only once that one is modelled)
        # did not help alone: screen the rest cheaply on top of the new model and retry those that help
        dismissed = {n for c in confounded for n in c["effects"][1:]}
        rest = [n for n in names if n not in selected and n not in pool and n not in dismissed]
        pool += _unmasked(problem, current, rest, workers)
        if not pool:
            break
        round_fits = _fit_many(problem, current, pool, workers, progress, f"round {len(selected) + 1}")
        for n in list(pool):
            if _at_bound(round_fits[n].model, n):
                pool.remove(n)
        for n in list(pool):
            if round_fits[n].bic - current.bic >= -BIC_THRESHOLD:
                confounded.append({
                    "effects": [chosen, n],
                    "regions": sorted({effect_types()[chosen].region, effect_types()[n].region}),
                    "note": f"{n} improved the fit alone (delta_bic {singles[n].bic - baseline.bic:.1f}) "
                            f"but adds nothing once {chosen} is in: they explain the same residual",
                })
                pool.remove(n)
    # backward pass: an effect selected early can become redundant once later ones are in
    dropped = []
    if len(selected) > 1:
        # the refits without each effect are independent until one is dropped: run them in parallel
        # and redo the rest serially only after a drop (the same results as the serial loop)
        order = list(selected)
        ahead = dict(zip(order, _run_parallel(problem, _without_job, [(n, current.model) for n in order], workers)))
        for name in order:
            without = ahead[name] if ahead is not None else _without_job(problem, name, current.model)
            d_held = problem.chi2(without.model, held) - problem.chi2(current.model, held)
            if without.bic - current.bic < BIC_THRESHOLD or (held.size and d_held < HELDOUT_CHI2_GAIN):
                selected.remove(name)
                dropped.append({"name": name, "delta_bic_when_removed": float(without.bic - current.bic),
                                "delta_heldout_chi2_when_removed": float(d_held)})
                current = without
                ahead = None  # later refits start from the reduced model
    if selected:
        current = refit_fresh_material(problem, current, workers)
    t3 = time.perf_counter()
    return Diagnosis(problem, baseline, candidates, selected, current, singles, confounded, dropped,
                     {"baseline_s": t1 - t0, "candidates_s": t2 - t1, "selection_s": t3 - t2})


# ----------------------------------------------------------------------------- JSON

def region_table(problem: Problem, model: Model) -> list:
    """Gap and bias per (region, incidence, polarization) for ``model``, all usable points."""
    idx_all = np.flatnonzero(problem.usable)
    r = np.full(problem.y.size, np.nan)
    r[idx_all] = problem.log_residual(model, idx_all)
    rows = []
    for ti in np.unique(problem.theta_i_deg):
        for pol in ("s", "p", "u"):
            for name in REGION_ORDER:
                sel = (problem.theta_i_deg == ti) & (problem.pol == pol) & (problem.region == name) & problem.usable
                if not sel.any():
                    continue
                v = r[sel]
                rows.append({"name": name, "theta_i_deg": float(ti), "polarization": pol,
                             "n_points": int(sel.sum()), "heldout": bool(ti in problem.heldout_deg),
                             "gap": float(np.sqrt(np.mean(v * v))), "bias": float(np.mean(v))})
    return rows


def to_json(d: Diagnosis) -> dict:
    """The OUT.json document of CONTRACTS §4.1 (plus extra fields)."""
    p = d.problem
    held, train = p.held_idx, p.train_idx
    base_rows = region_table(p, d.baseline.model)
    final_rows = region_table(p, d.final.model)
    # blame: per region, the selected effect whose single fit lowers that region's gap most
    single_rows = {n: region_table(p, d.single_fits[n].model) for n in d.selected}
    regions = []
    for i, row in enumerate(base_rows):
        row = dict(row)
        row["gap_final"] = final_rows[i]["gap"]
        row["bias_final"] = final_rows[i]["bias"]
        blamed, best = None, row["gap"]
        for n in d.selected:
            g = single_rows[n][i]["gap"]
            if g < 0.8 * best:
                blamed, best = n, g
        row["effect"] = blamed
        regions.append(row)
    noise_held = p.noise_level(held)
    noise_train = p.noise_level(train)
    final_params = {n: {k: float(v) for k, v in d.final.model.effect_params(n).items()} for n in d.selected}
    return {
        "gap_metric": GAP_METRIC,
        "gap_rule": "RMS over points of log10(measured/simulated), dex; points with brdf_per_sr > 2 x "
                    "brdf_std_per_sr / sqrt(n_repeats) (or > 0 without a std)",
        "heldout_theta_i_deg": [float(a) for a in p.heldout_deg],
        "train_theta_i_deg": [float(a) for a in np.unique(p.theta_i_deg) if a not in p.heldout_deg],
        "n_points": {"total": int(p.y.size), "usable": int(p.usable.sum()), "train": int(train.size), "heldout": int(held.size)},
        "rig": {k: float(v) for k, v in p.config.__dict__.items()},
        "baseline": {"heldout_gap": p.gap(d.baseline.model, held), "train_gap": p.gap(d.baseline.model, train),
                     "bic": d.baseline.bic, "chi2": d.baseline.chi2, "material": d.baseline.model.material(p.wavelength_nm).to_dict()},
        "regions": regions,
        "candidates": d.candidates,
        "selected_effects": list(d.selected),
        "selected_parameters": final_params,
        "confounded": d.confounded,
        "dropped_effects": d.dropped,
        "final": {"heldout_gap": p.gap(d.final.model, held), "train_gap": p.gap(d.final.model, train),
                  "bic": d.final.bic, "material": d.final.model.material(p.wavelength_nm).to_dict()},
        "noise_level": {"heldout_gap": noise_held, "train_gap": noise_train,
                        "meaning": "the gap a perfect model would leave: RMS of std/(sqrt(n) brdf ln 10) on the same points"},
        "thresholds": {"delta_bic": -BIC_THRESHOLD, "delta_heldout_chi2": -HELDOUT_CHI2_GAIN},
        "timings_s": d.timings,
    }
