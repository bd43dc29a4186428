"""Fitting candidates: the baseline (material only), each catalogue effect on top of a model,
fresh-material refits, the masking screen and the backward pass's refits. Independent fits run
through :func:`rig.diagnose.tasks.run_tasks` (serially or on the caller's executor)."""
from __future__ import annotations

import math

from rig.diagnose.params import Fit, Model, effect_specs, material_specs
from rig.diagnose.problem import Problem
from rig.diagnose.starts import effect_starts, material_starts, rescale_lobes
from rig.diagnose.tasks import run_tasks

#: BIC must drop by more than this to keep an effect ("very strong" evidence, Kass & Raftery 1995).
BIC_THRESHOLD = 10.0


def at_bound(model: Model, name: str) -> list:
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


def _baseline_job(problem: Problem, start: Model, max_nfev: int) -> Fit:
    return problem.fit(rescale_lobes(problem, start), max_nfev=max_nfev)


def fit_baseline(problem: Problem, executor=None) -> Fit:
    """Material only, one or two lobes, several starts (on ``executor``, :mod:`rig.diagnose.tasks`); lowest BIC
    wins (first in start order on ties, as a serial loop)."""
    args = [(start, 80 if n_lobes == 1 else 120) for n_lobes in (1, 2) for start in material_starts(problem, n_lobes)]
    best: Fit | None = None
    for f in run_tasks(problem, _baseline_job, args, executor):
        if best is None or f.bic < best.bic:
            best = f
    if best is None:
        raise ValueError("the baseline has no starting model")
    # polish the winner
    polished = problem.fit(best.model, max_nfev=100)
    return polished if polished.bic <= best.bic else best


def effect_prefits(problem: Problem, base: Fit, name: str) -> Fit:
    """``base`` plus effect ``name`` with only the effect's parameters free (material fixed,
    cheap), from each of the effect's starts; the best."""
    best: Fit | None = None
    for start in effect_starts(problem, name):
        vals = dict(base.model.values)
        vals.update({(name, p): v for p, v in start.items()})
        model = Model(base.model.n_lobes, vals, base.model.effects + (name,))
        f = problem.fit(model, free={(name, p) for p in start}, max_nfev=12)
        if best is None or f.chi2 < best.chi2:
            best = f
    if best is None:
        raise ValueError(f"effect {name!r} has no starting values")
    return best


def fit_with_effect(problem: Problem, base: Fit, name: str, max_nfev=25) -> Fit:
    """``base`` plus effect ``name``: the effect's parameters alone from each start (material
    fixed, cheap), then everything jointly from the best of those."""
    best = effect_prefits(problem, base, name)
    joint = problem.fit(best.model, max_nfev=max_nfev)
    return joint if joint.chi2 <= best.chi2 else best


def refit_fresh_material(problem: Problem, fit: Fit, executor=None) -> Fit:
    """``fit``'s effects held at their values, the material refitted from the baseline's fresh
    starts (one and two lobes), then everything jointly from the best; the better of that and
    ``fit`` by BIC. The joint fits start from the baseline material, which has already bent
    to imitate the effects (a tilt lowers the peak: the baseline lowers n and widens the lobe)
    and can hold the joint fit in a local minimum."""
    effect_vals = {k: v for k, v in fit.model.values.items() if k[0] != "material"}
    args = [(Model(n_lobes, {**start.values, **effect_vals}, fit.model.effects),)
            for n_lobes in (1, 2) for start in material_starts(problem, n_lobes)]
    best = fit
    for f in run_tasks(problem, _fresh_job, args, executor):
        if f.bic < best.bic:
            best = f
    return best


def _fresh_job(problem: Problem, model: Model) -> Fit:
    m = rescale_lobes(problem, model)
    free = {(s.owner, s.name) for s in material_specs(m.n_lobes)}
    return problem.fit(problem.fit(m, free=free, max_nfev=60).model, max_nfev=40)


def unmasked(problem: Problem, base: Fit, names, executor=None) -> list:
    """Those of ``names`` whose effect-only fit on top of ``base`` lowers chi^2 by more than the
    BIC threshold plus the effect's parameter penalty (a cheap screen: material fixed)."""
    names = list(names)
    fits = run_tasks(problem, effect_prefits, [(base, n) for n in names], executor)
    log_n = math.log(max(problem.train_idx.size, 1))
    return [n for n, f in zip(names, fits)
            if base.chi2 - f.chi2 > BIC_THRESHOLD + len(effect_specs(n)) * log_n and not at_bound(f.model, n)]


def fit_many(problem: Problem, base: Fit, names, executor=None, progress: bool = False, desc: str = "") -> dict:
    """fit_with_effect for each name (on ``executor``)."""
    names = list(names)
    fits = run_tasks(problem, fit_with_effect, [(base, n) for n in names], executor, progress, desc)
    return dict(zip(names, fits))


def without_effect(problem: Problem, name: str, model: Model) -> Fit:
    """``model`` refitted without effect ``name`` (the backward pass)."""
    rest = tuple(e for e in model.effects if e != name)
    vals = {k: v for k, v in model.values.items() if k[0] != name}
    return problem.fit(Model(model.n_lobes, vals, rest), max_nfev=25)
