"""Fit a sum of BRDF components to a measured scan (seed paper section 3, Figs. 5-6).

Model spec: component types joined by ``+``, e.g. ``"lambertian+k_correlation"``,
``"lambertian+k_correlation+k_correlation"`` (the seed paper's three-component form),
``"lambertian+microfacet"``. Free parameters (names used in ``fixed``, ``bounds``,
``initial`` and in :attr:`FitResult.params`):

=================  ==========================  ============  =========
component          parameter                   bounds        scale
=================  ==========================  ============  =========
lambertian         ``lambertian.rd``           1e-6 .. 0.99  log
k_correlation      ``k_correlation.sigma_nm``  1e-3 .. 300   log
                   ``k_correlation.lc_um``     0.05 .. 1e3   log
                   ``k_correlation.s``         1 .. 6        linear
microfacet         ``microfacet.alpha``        1e-3 .. 2     log
                   ``microfacet.weight``       1e-6 .. 1e3   log
abg                ``abg.a``                   1e-10 .. 1e4  log
                   ``abg.b``                   1e-10 .. 1    log
                   ``abg.g``                   0 .. 4        linear
harvey_shack       ``harvey_shack.b0``         1e-6 .. 1e8   log
                   ``harvey_shack.l``          1e-5 .. 1     log
                   ``harvey_shack.s``          -8 .. 0       linear
(shared)           ``n``                       1.05 .. 3     linear
=================  ==========================  ============  =========

Each component declares its own parameters, bounds, scale and starts in its own file (its
``fit_params``, :mod:`materials.fit_params`); this table is what they declare, and the fit reads
them only through :func:`materials.fit_params.fit_params` (so does the rig diagnosis). A new
fittable model is its file with ``fit_params``, nothing here.

A type used twice is numbered: ``k_correlation1.sigma_nm``, ``k_correlation2.sigma_nm``.
Every component with a refractive index (k_correlation, microfacet) uses the ONE
shared index ``n``, and s- and p-polarized rows are fitted jointly with it
(PHYSICS §1: one n explains s and p; a constant R cannot).

Residuals are in log10 space, weighted by the measured standard deviation::

    r_j = (log10 f_model(j) - log10 f_meas(j)) / sigma_log10(j),
    sigma_log10 = brdf_std_per_sr / (brdf_per_sr ln 10)

``brdf_std_per_sr`` is taken as ABSOLUTE (not a relative weight): the covariance is
``(J^T J)^-1`` at the solution, transformed to physical parameters, and is NOT rescaled
by the reduced chi-square (reported separately as ``chi2_reduced``; multiply the
covariance by it if you distrust the stds). Points with unknown std (NaN) use
``default_relative_std``; every relative std is floored at ``min_relative_std`` (so a
point with three identical readings does not get infinite weight). Points whose
``brdf_per_sr`` is NaN, zero or negative (:attr:`materials.scan.Scan.flagged`) or whose
``theta_r`` is 90 deg are excluded and counted in ``n_excluded``.

Optimiser: ``scipy.optimize.least_squares`` (trust-region reflective) on bounded
parameters, positive ones in log space; multi-start (a heuristic start, then
``n_starts - 1`` starts drawn from ``numpy.random.default_rng(seed)`` in plausible
ranges); the lowest cost wins.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

import materials.abg  # noqa: F401  (registers "abg")
import materials.harvey_shack  # noqa: F401  (registers "harvey_shack")
import materials.kcorrelation  # noqa: F401  (registers "k_correlation")
import materials.lambertian  # noqa: F401  (registers "lambertian")
import materials.microfacet  # noqa: F401  (registers "microfacet")
from materials.albedo import directional_hemispherical_reflectance
from materials.base import directions_from_angles
from materials.composite import Composite
from materials.fit_params import FitParam, fit_params, fittable_types
from materials.material import Material
from materials.registry import build_component, component_types
from materials.scan import Scan

LN10 = math.log(10.0)
RHO_THETA_I_DEG = (0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0, 85.0)


class FitError(ValueError):
    """A fit request that cannot be carried out (bad spec, no usable points)."""


@dataclass(frozen=True)
class ParamDef:
    """One fitted (or fixed) parameter of a :class:`ModelSpec`."""

    name: str  # full name, e.g. "k_correlation.sigma_nm" or "n"
    key: str  # component key, e.g. "sigma_nm"
    component: int | None  # index in the spec, None for the shared n
    lower: float
    upper: float
    log: bool
    start: float | None
    plausible: tuple | None


class ModelSpec:
    """A parsed model spec: maps a vector of free parameters to components.

    Parameters
    ----------
    spec : str
        Component types joined by ``+`` (see module docstring).
    wavelength_nm : float
    fixed, bounds, initial : dict, optional
        By parameter name: values held fixed; (lower, upper) overriding the defaults;
        starting values for the first start.

    Notes
    -----
    Public so that other fitters (e.g. a fit through the rig model) can reuse the
    parameterisation: ``x0``, ``lower_x``, ``upper_x``, ``components(x)``, ``params(x)``.
    """

    def __init__(self, spec: str, wavelength_nm: float, fixed=None, bounds=None, initial=None):
        types = [t.strip() for t in str(spec).split("+")]
        known = fittable_types()
        if not types or any(t not in known for t in types):
            bad = [t for t in types if t not in known]
            raise FitError(f"model: unknown component type {bad[0]!r} in {spec!r}; "
                           f"fit supports {', '.join(known)} joined by '+'")
        self.spec = "+".join(types)
        self.types = tuple(types)
        self.wavelength_nm = float(wavelength_nm)
        counts = {t: types.count(t) for t in types}
        seen: dict[str, int] = {}
        defs = []
        shared: dict[str, FitParam] = {}  # one value for the whole model, after the components' own
        self._shared_keys: list[tuple[str, ...]] = []
        for i, t in enumerate(types):
            seen[t] = seen.get(t, 0) + 1
            prefix = t if counts[t] == 1 else f"{t}{seen[t]}"
            for p in fit_params(t):
                if p.shared:
                    if shared.setdefault(p.key, p) != p:
                        raise FitError(f"model: {t!r} declares the shared parameter {p.key!r} differently "
                                       f"from another component of {spec!r}")
                    continue
                defs.append(ParamDef(f"{prefix}.{p.key}", p.key, i, p.lower, p.upper, p.log, p.start, p.plausible))
            self._shared_keys.append(tuple(p.key for p in fit_params(t) if p.shared))
        for key, p in shared.items():
            defs.append(ParamDef(key, key, None, p.lower, p.upper, p.log, p.start, p.plausible))
        self._pass_wavelength = tuple("wavelength_nm" in {f.name for f in dataclasses.fields(component_types()[t])}
                                      for t in types)
        self.all_params = tuple(defs)
        names = [d.name for d in defs]
        fixed = dict(fixed or {})
        bounds = dict(bounds or {})
        initial = dict(initial or {})
        for what, given in (("fixed", fixed), ("bounds", bounds), ("initial", initial)):
            unknown = sorted(set(given) - set(names))
            if unknown:
                raise FitError(f"{what}: unknown parameter(s) {', '.join(unknown)} for model {self.spec!r}; "
                               f"parameters: {', '.join(names)}")
        new_defs = []
        for d in defs:
            lo, hi = bounds.get(d.name, (d.lower, d.upper))
            lo, hi = float(lo), float(hi)
            if not lo < hi or (d.log and lo <= 0):
                raise FitError(f"bounds: {d.name} needs lower < upper{' and lower > 0' if d.log else ''}, got ({lo}, {hi})")
            new_defs.append(ParamDef(d.name, d.key, d.component, lo, hi, d.log,
                                     initial.get(d.name, d.start), d.plausible))
        self.all_params = tuple(new_defs)
        self.fixed = {k: float(v) for k, v in fixed.items()}
        self.free = tuple(d for d in self.all_params if d.name not in self.fixed)
        self.free_names = tuple(d.name for d in self.free)

    # ------------------------------------------------------------------ vectors
    def to_x(self, values: dict) -> np.ndarray:
        """Physical values (by name) -> optimiser vector (log for log-scaled parameters)."""
        out = []
        for d in self.free:
            v = float(np.clip(values[d.name], d.lower, d.upper))
            out.append(math.log(v) if d.log else v)
        return np.array(out)

    def values(self, x) -> dict:
        """Optimiser vector -> all parameter values (free and fixed) by name."""
        out = dict(self.fixed)
        for d, xi in zip(self.free, np.asarray(x, float)):
            out[d.name] = math.exp(xi) if d.log else float(xi)
        return {d.name: out[d.name] for d in self.all_params}

    @property
    def lower_x(self) -> np.ndarray:
        return np.array([math.log(d.lower) if d.log else d.lower for d in self.free])

    @property
    def upper_x(self) -> np.ndarray:
        return np.array([math.log(d.upper) if d.log else d.upper for d in self.free])

    def components(self, x) -> list:
        """Component objects for optimiser vector ``x``."""
        vals = self.values(x)
        comps = []
        for i, t in enumerate(self.types):
            entry = {"type": t}
            for d in self.all_params:
                if d.component == i:
                    entry[d.key] = vals[d.name]
            for key in self._shared_keys[i]:
                entry[key] = vals[key]
            if self._pass_wavelength[i]:  # a component that scatters by wavelength gets the scan's
                entry["wavelength_nm"] = self.wavelength_nm
            comps.append(build_component(entry, where=f"{self.spec} component {i}"))
        return comps

    def starts(self, heuristic: dict, n_starts: int, seed: int) -> list[np.ndarray]:
        """The first start from ``heuristic``/defaults, the rest random in plausible ranges."""
        first = {}
        for d in self.free:
            v = d.start if d.start is not None else heuristic.get(d.key)
            first[d.name] = v if v is not None else math.sqrt(d.lower * d.upper) if d.log else 0.5 * (d.lower + d.upper)
        out = [self.to_x(first)]
        rng = np.random.default_rng(seed)
        for _ in range(max(0, n_starts - 1)):
            vals = {}
            for d in self.free:
                if d.plausible is None:
                    base = first[d.name]
                    lo, hi = base / 2.0, base * 2.0
                else:
                    lo, hi = d.plausible
                u = rng.random()
                vals[d.name] = math.exp(math.log(lo) + u * math.log(hi / lo)) if d.log else lo + u * (hi - lo)
            out.append(self.to_x(vals))
        return out


def evaluate_components(components, scan: Scan) -> np.ndarray:
    """Sum of the components' BRDFs at the scan's angles and polarizations, (n,) 1/sr."""
    return _ScanGeometry(scan).evaluate(components)


class _ScanGeometry:
    """Directions of a scan's rows, grouped by polarization, computed once per fit."""

    def __init__(self, scan: Scan):
        wi, wo = directions_from_angles(scan.theta_i, scan.theta_r, scan.phi_r)
        self.n = len(scan)
        self.groups = [(pol, np.flatnonzero(scan.polarization == pol)) for pol in scan.polarizations]
        self.groups = [(pol, idx, wi[idx], wo[idx]) for pol, idx in self.groups]

    def evaluate(self, components) -> np.ndarray:
        out = np.zeros(self.n)
        for pol, idx, wi, wo in self.groups:
            total = components[0].brdf(wi, wo, pol)
            for c in components[1:]:
                total = total + c.brdf(wi, wo, pol)
            out[idx] = total
        return out


@dataclass(frozen=True, eq=False)
class FitResult:
    """Outcome of :func:`fit`.

    Attributes
    ----------
    params, stderr : dict[str, float]
        Fitted values and 1-sigma standard errors by name (unit-suffixed, see module doc);
        fixed parameters have stderr 0; inf where the Jacobian is rank-deficient.
    cov : (k, k) covariance of the free parameters (order ``free_names``), physical units.
    success, message : from the best least-squares run.
    n_eval : model evaluations over all starts, finite-difference Jacobians included.
    residuals : (m,) weighted log10 residuals of the fitted points.
    rms_log10 : dict[(theta_i_deg, polarization), float], unweighted RMS of
        log10(model / measured) over fitted points.
    rho : dict with "theta_i_deg" and one list per polarization: rho(theta_i) of the fit.
    chi2, chi2_reduced : weighted sum of squares and its value per degree of freedom.
    n_points, n_excluded : fitted points; points left out (flagged BRDF, theta_r = 90 deg).
    components : the fitted component objects; ``material()`` wraps them.
    fit_mask : (n,) bool over the scan rows: which were fitted.
    log10_ratio : (m,) unweighted log10(model / measured) of the fitted points.
    """

    model: str
    params: dict
    stderr: dict
    cov: np.ndarray
    free_names: tuple
    success: bool
    message: str
    n_eval: int
    residuals: np.ndarray
    rms_log10: dict
    rho: dict
    chi2: float
    chi2_reduced: float
    n_points: int
    n_excluded: int
    n_starts: int
    wavelength_nm: float
    components: tuple = field(repr=False, default=())
    fit_mask: np.ndarray = field(repr=False, default=None)
    log10_ratio: np.ndarray = field(repr=False, default=None)
    group_counts: dict = field(repr=False, default_factory=dict)

    @property
    def rms_log10_total(self) -> float:
        r = self.log10_ratio
        return float(np.sqrt(np.mean(r**2))) if r.size else float("nan")

    def material(self, name: str = "fitted", description=None, provenance=None) -> Material:
        """The fitted components as a :class:`materials.material.Material`."""
        return Material(name=name, wavelength_nm=self.wavelength_nm, components=tuple(self.components),
                        description=description, provenance=provenance)

    def rms_table(self) -> list[dict]:
        """rms_log10 as JSON-ready rows."""
        return [{"theta_i_deg": t, "polarization": p, "rms_log10": v, "n_points": self.group_counts[(t, p)]}
                for (t, p), v in self.rms_log10.items()]

    def to_json(self) -> dict:
        """A JSON-ready report."""
        return {
            "model": self.model,
            "wavelength_nm": self.wavelength_nm,
            "params": self.params,
            "stderr": {k: (v if math.isfinite(v) else None) for k, v in self.stderr.items()},
            "free_parameters": list(self.free_names),
            "success": self.success,
            "message": self.message,
            "n_eval": self.n_eval,
            "n_starts": self.n_starts,
            "n_points": self.n_points,
            "n_excluded": self.n_excluded,
            "chi2": self.chi2,
            "chi2_reduced": self.chi2_reduced,
            "rms_log10_total": self.rms_log10_total,
            "rms_log10": self.rms_table(),
            "rho": self.rho,
            "components": [c.to_dict() for c in self.components],
        }


def _heuristic(scan: Scan, ok: np.ndarray) -> dict:
    brdf = scan.brdf_per_sr[ok]
    return {"rd": float(np.clip(np.pi * np.quantile(brdf, 0.05), 1e-5, 0.9))}


def _covariance(jac: np.ndarray, x: np.ndarray, spec: ModelSpec):
    """(J^T J)^-1 via SVD in optimiser space, then d(phys)/dx = phys for log parameters."""
    _, s, vt = np.linalg.svd(jac, full_matrices=False)
    tol = np.finfo(float).eps * max(jac.shape) * (s[0] if s.size else 0.0)
    keep = s > tol
    cov_x = (vt[keep].T / s[keep] ** 2) @ vt[keep]
    if not np.all(keep):
        # directions the data do not constrain: infinite variance for the parameters in them
        weak = np.any(np.abs(vt[~keep]) > 1e-3, axis=0)
        cov_x[weak, :] = np.inf
        cov_x[:, weak] = np.inf
    vals = spec.values(x)
    scale = np.array([vals[d.name] if d.log else 1.0 for d in spec.free])
    with np.errstate(invalid="ignore"):
        return cov_x * scale[:, None] * scale[None, :]


def fit(scan: Scan, model: str = "lambertian+k_correlation", *, fixed=None, bounds=None, initial=None,
        n_starts: int = 6, seed: int = 0, default_relative_std: float = 0.05,
        min_relative_std: float = 0.005, loss: str = "linear", predict=None,
        rho_theta_i_deg=RHO_THETA_I_DEG, max_nfev: int | None = None, reweight: bool = True,
        std_of_mean: bool = False, progress=None) -> FitResult:
    """Fit the components of ``model`` to ``scan`` (see module docstring for the method).

    Parameters
    ----------
    scan : Scan
        One wavelength; any incidence angles; s, p and/or u rows.
    model : str
        Spec such as ``"lambertian+k_correlation"``.
    fixed, bounds, initial : dict, optional
        By parameter name (e.g. ``{"n": 1.5}``, ``{"k_correlation.s": (2, 4)}``).
    n_starts, seed : int
        Multi-start count and the seed of the random starts.
    default_relative_std, min_relative_std : float
        std used where the scan's is NaN; floor on std / brdf.
    loss : str
        ``least_squares`` loss ("linear" = plain chi-square; "soft_l1" for outliers).
    predict : callable, optional
        ``predict(components, scan) -> (n,) BRDF`` replacing the direct evaluation
        (e.g. a rig forward model); default :func:`evaluate_components`.
    rho_theta_i_deg : sequence of float
        Incidence angles of the reported rho(theta_i) table.
    reweight : bool
        After the multi-start, refit once with ``sigma_log10 = std / (f_fit ln 10)``
        (weights from the fitted model, not the noisy measurement; default True).
    std_of_mean : bool
        Divide ``brdf_std_per_sr`` by sqrt(n_repeats) (when the column is the std of
        single readings and the readings are independent). Default False: the std
        is used as given, which is conservative for repeated readings.
    progress : callable, optional
        Called as ``progress(1)`` after each start (e.g. ``tqdm.update``).

    Returns
    -------
    FitResult
    """
    wavelengths = np.unique(scan.wavelength_nm)
    if len(wavelengths) != 1:
        raise FitError(f"scan: one wavelength per fit, got {wavelengths.tolist()} nm")
    spec = ModelSpec(model, wavelengths[0], fixed=fixed, bounds=bounds, initial=initial)
    ok = ~scan.flagged & (scan.theta_r < np.pi / 2 - 1e-9)
    n_excluded = int((~ok).sum())
    if ok.sum() <= len(spec.free):
        raise FitError(f"scan: {int(ok.sum())} usable points for {len(spec.free)} free parameters "
                       f"({n_excluded} excluded: NaN/<=0 BRDF or theta_r = 90 deg)")
    data = scan.select(ok)
    meas = data.brdf_per_sr
    std = data.brdf_std_per_sr / (np.sqrt(np.maximum(data.n_repeats, 1)) if std_of_mean else 1.0)
    log_meas = np.log10(meas)
    if predict is None:
        geometry = _ScanGeometry(data)

        def predict(components, _scan):
            return geometry.evaluate(components)

    def sigma_log10_for(reference):
        rel = std / reference
        rel = np.where(np.isfinite(rel), rel, default_relative_std)
        return np.maximum(rel, min_relative_std) / LN10

    calls = [0]  # model evaluations, including the finite-difference Jacobian's

    def make_residuals(sigma_log10):
        def residuals(x):
            calls[0] += 1
            model_brdf = predict(spec.components(x), data)
            return (np.log10(np.maximum(model_brdf, 1e-300)) - log_meas) / sigma_log10
        return residuals

    def solve(residuals, x0):
        x0 = np.clip(x0, spec.lower_x, spec.upper_x)
        return least_squares(residuals, x0, bounds=(spec.lower_x, spec.upper_x), method="trf",
                             x_scale="jac", loss=loss, max_nfev=max_nfev or 200 * (len(x0) + 1))

    sigma_log10 = sigma_log10_for(meas)
    residuals = make_residuals(sigma_log10)
    best = None
    starts = spec.starts(_heuristic(scan, ok), n_starts, seed) if spec.free else []
    for x0 in starts:
        res = solve(residuals, x0)
        if best is None or res.cost < best.cost:
            best = res
        if progress is not None:
            progress(1)
    if best is not None and reweight:
        # Weights std / measured favour points that fluctuated up (Neyman chi-square bias,
        # ~1.5 rel^2 in the level); one pass with std / fitted model removes it.
        sigma_log10 = sigma_log10_for(predict(spec.components(best.x), data))
        residuals = make_residuals(sigma_log10)
        best2 = solve(residuals, best.x)
        best = best2
    if best is None:  # everything fixed
        x_best = np.zeros(0)
        r = residuals(x_best)
        success, message, jac = True, "no free parameters", np.zeros((len(r), 0))
    else:
        x_best, success, message, jac = best.x, bool(best.success), str(best.message), best.jac
        r = residuals(x_best)
    cov = _covariance(jac, x_best, spec) if len(x_best) else np.zeros((0, 0))
    vals = spec.values(x_best)
    stderr = {name: 0.0 for name in vals}
    for i, name in enumerate(spec.free_names):
        stderr[name] = float(np.sqrt(cov[i, i])) if np.isfinite(cov[i, i]) and cov[i, i] >= 0 else float("inf")
    comps = spec.components(x_best)
    model_brdf = predict(comps, data)
    ratio = np.log10(np.maximum(model_brdf, 1e-300)) - log_meas
    rms, counts = {}, {}
    for (t, p), _ in data.groups():
        m = (data.theta_i_deg == t) & (data.polarization == p)
        rms[(t, p)] = float(np.sqrt(np.mean(ratio[m] ** 2)))
        counts[(t, p)] = int(m.sum())
    chi2 = float(np.sum(r**2))
    dof = max(1, len(r) - len(x_best))
    rho = {"theta_i_deg": list(map(float, rho_theta_i_deg))}
    theta = np.radians(np.asarray(rho_theta_i_deg, float))
    total = Composite(tuple(comps))
    for pol in data.polarizations:
        rho[pol] = [float(v) for v in directional_hemispherical_reflectance(total, theta, pol)]
    result = FitResult(
        model=spec.spec, params=vals, stderr=stderr, cov=cov, free_names=spec.free_names,
        success=success, message=message, n_eval=calls[0], residuals=r, rms_log10=rms, rho=rho,
        chi2=chi2, chi2_reduced=chi2 / dof, n_points=len(r), n_excluded=n_excluded,
        n_starts=len(starts), wavelength_nm=float(wavelengths[0]), components=tuple(comps), fit_mask=ok,
        log10_ratio=ratio, group_counts=counts,
    )
    return result


def format_fit_report(result: FitResult) -> str:
    """Human-readable fit report: parameters +- 1 sigma, rms log10 per incidence angle, rho table."""
    lines = [f"model: {result.model}   wavelength: {result.wavelength_nm:g} nm",
             f"points: {result.n_points} fitted, {result.n_excluded} excluded (NaN/<=0 BRDF or theta_r = 90 deg)",
             f"success: {result.success} ({result.message}); {result.n_starts} starts, {result.n_eval} evaluations",
             f"chi2 = {result.chi2:.4g}, chi2/dof = {result.chi2_reduced:.4g} "
             "(stderr from (J^T J)^-1 with the scan's std as absolute; not rescaled)",
             "", "parameters (1 sigma):"]
    for name, value in result.params.items():
        err = result.stderr[name]
        tag = " (fixed)" if name not in result.free_names else ""
        lines.append(f"  {name:28s} {value:12.6g} +- {err:.3g}{tag}")
    lines += ["", "rms log10(model/measured) per incidence angle (dex):"]
    for row in result.rms_table():
        lines.append(f"  theta_i = {row['theta_i_deg']:5.1f} deg  {row['polarization']}  "
                     f"{row['rms_log10']:.4f}  ({row['n_points']} points)")
    lines.append(f"  all: {result.rms_log10_total:.4f}")
    pols = [p for p in ("s", "p", "u") if p in result.rho]
    lines += ["", "directional-hemispherical reflectance rho(theta_i):",
              "  theta_i_deg " + " ".join(f"{p:>9s}" for p in pols)]
    for k, t in enumerate(result.rho["theta_i_deg"]):
        lines.append(f"  {t:11.1f} " + " ".join(f"{result.rho[p][k]:9.5f}" for p in pols))
    return "\n".join(lines)
