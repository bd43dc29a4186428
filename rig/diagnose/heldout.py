"""Held-out scoring: how a fitted model predicts the incidence angles the fit never saw, and the
candidate table of CONTRACTS 4.1 (each effect alone on top of the baseline)."""
from __future__ import annotations

from rig.diagnose.candidates import at_bound
from rig.diagnose.params import Fit
from rig.diagnose.problem import Problem
from rig.effects import effect_types

#: The held-out chi^2 (predictive fit on incidences the fit never saw) must fall by more than
#: this, with the held-out gap falling too, for an effect to be kept.
HELDOUT_CHI2_GAIN = 10.0


def predicts_better(problem: Problem, new: Fit, current: Fit, current_gap) -> bool:
    """True when ``new`` predicts the held-out points better than ``current``: chi^2 down by more
    than :data:`HELDOUT_CHI2_GAIN` and the gap down too (always true without held-out points)."""
    held = problem.held_idx
    if held.size == 0:
        return True
    d_held = problem.chi2(new.model, held) - problem.chi2(current.model, held)
    return d_held < -HELDOUT_CHI2_GAIN and problem.gap(new.model, held) < current_gap


def candidate_row(problem: Problem, baseline: Fit, fit: Fit, name: str, gap_before) -> dict:
    """One entry of the JSON's ``candidates``: effect ``name`` fitted alone on the baseline."""
    held = problem.held_idx
    return {
        "name": name,
        "fitted": {p: float(v) for p, v in fit.model.effect_params(name).items()},
        "delta_bic": float(fit.bic - baseline.bic),
        "heldout_gap_before": gap_before,
        "heldout_gap_after": problem.gap(fit.model, held),
        "train_gap_after": problem.gap(fit.model, problem.train_idx),
        "delta_heldout_chi2": problem.chi2(fit.model, held) - problem.chi2(baseline.model, held),
        "region": effect_types()[name].region,
        "at_bound": at_bound(fit.model, name),
    }


def rank_candidates(rows: list) -> list:
    """Best first: lowest delta BIC, ties by the held-out gap after."""
    return sorted(rows, key=lambda c: (c["delta_bic"], c["heldout_gap_after"] if c["heldout_gap_after"] is not None else 0.0))
