"""Telling twin effects apart: effects whose signatures are nearly the same (``twin`` in the
effect's own file: a stage offset d and an arm offset -2d move the specular peak alike).

Forward selection adds the twin whose *single* fit is best, before the other effects are in;
with a stray background not yet modelled, the wrong offset can win (its slightly different
footprint and Fresnel terms soak up part of the floor). So once the model is complete, each
selected effect with a twin is checked: the twin is put in its place (from the parameters that
move the peak alike, :meth:`twin_params`), fitted, and the two are compared on all the evidence
the data hold, the training BIC plus the held-out chi^2 (both in chi^2 units):

* the twin better by more than :data:`TWIN_EVIDENCE`: it replaces the selected one;
* the selected one better by more than that: the data tell them apart (kept);
* otherwise: the data cannot tell them apart, and they are reported confounded (the offset
  signatures differ only through the incidence-dependent Fresnel factor, the footprint and
  1/cos terms, which a scan may not resolve).
"""
from __future__ import annotations

from rig.diagnose.params import Fit, Model
from rig.diagnose.problem import Problem
from rig.effects import effect_types
from rig.effects.registry import twin_of

#: Evidence (chi^2 units) needed to call one twin better than the other (= the BIC threshold).
TWIN_EVIDENCE = 10.0


def _with_twin(model: Model, name: str, twin: str) -> Model:
    cls = twin_of(name)
    if cls is None:
        raise ValueError(f"effect {name!r} has no twin")
    params = model.effect_params(name)
    vals = {k: v for k, v in model.values.items() if k[0] != name}
    vals.update({(twin, p): v for p, v in cls.twin_params(**params).items()})
    effects = tuple(twin if e == name else e for e in model.effects)
    return Model(model.n_lobes, vals, effects)


def fit_twin(problem: Problem, current: Fit, name: str) -> Fit:
    """``current`` with effect ``name`` replaced by its twin: the twin's parameters alone, then jointly."""
    cls = twin_of(name)
    if cls is None:
        raise ValueError(f"effect {name!r} has no twin")
    twin = cls.twin
    start = _with_twin(current.model, name, twin)
    free = {(twin, p) for p in effect_types()[twin].fit_space}
    alone = problem.fit(start, free=free, max_nfev=15)
    joint = problem.fit(alone.model, max_nfev=40)
    return joint if joint.chi2 <= alone.chi2 else alone


def check_twins(problem: Problem, current: Fit, selected: list, allowed=None) -> tuple:
    """(fit, selected, checks, confounded): ``current`` with each twin decision applied (module doc).
    ``allowed``: the candidate names (``--effects``); a twin outside them is not tried."""
    held = problem.held_idx
    checks, confounded = [], []
    selected = list(selected)
    for name in list(selected):
        cls = twin_of(name)
        twin = cls.twin if cls is not None else None
        if twin is None or twin in selected or (allowed is not None and twin not in allowed):
            continue
        alt = fit_twin(problem, current, name)
        d_bic = alt.bic - current.bic
        d_held = problem.chi2(alt.model, held) - problem.chi2(current.model, held)
        evidence = d_bic + d_held  # < 0: the twin explains the data better
        row = {"selected": name, "alternative": twin, "delta_bic_alternative": float(d_bic),
               "delta_heldout_chi2_alternative": float(d_held),
               "alternative_fitted": {p: float(v) for p, v in alt.model.effect_params(twin).items()}}
        if evidence < -TWIN_EVIDENCE:
            row["verdict"] = f"replaced: the data prefer {twin} (evidence {-evidence:.1f})"
            selected[selected.index(name)] = twin
            current = alt
        elif evidence > TWIN_EVIDENCE:
            row["verdict"] = f"told apart: {name} better by {evidence:.1f}"
        else:
            row["verdict"] = f"not distinguishable (evidence {abs(evidence):.1f} < {TWIN_EVIDENCE:g})"
            confounded.append({
                "effects": [name, twin],
                "regions": sorted({effect_types()[name].region, effect_types()[twin].region}),
                "note": f"the data cannot tell {name} from {twin}: with {twin} in its place the fit changes by "
                        f"{d_bic:+.1f} in BIC and {d_held:+.1f} in held-out chi^2; {name} is reported because "
                        f"it was found first",
            })
        checks.append(row)
    return current, selected, checks, confounded
