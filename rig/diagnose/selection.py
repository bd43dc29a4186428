"""Forward selection of effects (with the masking screen and the backward pass), and
:func:`diagnose`, which runs the whole method of the package doc."""
from __future__ import annotations

import time
from dataclasses import dataclass, field

from materials.scan import Scan
from rig.diagnose.candidates import (BIC_THRESHOLD, at_bound, fit_baseline, fit_many, refit_fresh_material, unmasked,
                                     without_effect)
from rig.diagnose.heldout import HELDOUT_CHI2_GAIN, candidate_row, predicts_better, rank_candidates
from rig.diagnose.params import Fit
from rig.diagnose.problem import DiagnoseError, Problem
from rig.diagnose.tasks import run_tasks
from rig.diagnose.twins import check_twins
from rig.effects import CATALOGUE, effect_types
from rig.instrument import RigConfig

#: Forward selection retries at most this many of the candidates that helped alone (best first).
MAX_RETRIED = 6


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
    twin_checks: list = field(default_factory=list)  # rig.diagnose.twins: offsets told apart or not


def diagnose(scan: Scan, holdout_theta_i_deg=None, effects=None, config: RigConfig | None = None,
             progress: bool = False, executor=None, workers: int = 1) -> Diagnosis:
    """Fit ``scan`` through the rig model and rank instrument effects (package doc).

    Independent fits run on ``executor`` (a ``concurrent.futures`` executor the caller owns,
    e.g. ``ProcessPoolExecutor(2)``); without one, ``workers > 1`` makes a process pool for
    this call, and ``workers = 1`` runs serially. The results are the same either way.
    """
    if executor is None and workers > 1:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(max_workers=workers) as processes:
            return diagnose(scan, holdout_theta_i_deg, effects, config, progress, executor=processes)
    names = list(CATALOGUE if not effects else effects)
    for n in names:
        if n not in effect_types():
            raise DiagnoseError(f"--effects: unknown effect {n!r}; known: {', '.join(effect_types())}")
    t0 = time.perf_counter()
    problem = Problem(scan, holdout_theta_i_deg, config)
    baseline = fit_baseline(problem, executor)
    t1 = time.perf_counter()
    held = problem.held_idx
    gap_before = problem.gap(baseline.model, held)

    singles = fit_many(problem, baseline, names, executor, progress, "candidates")
    t2 = time.perf_counter()

    candidates = rank_candidates([candidate_row(problem, baseline, singles[n], n, gap_before) for n in names])

    # forward selection
    selected: list[str] = []
    confounded: list[dict] = []
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
            if f.bic - current.bic >= -BIC_THRESHOLD:
                break
            if predicts_better(problem, f, current, current_gap):
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
        pool += unmasked(problem, current, rest, executor)
        if not pool:
            break
        round_fits = fit_many(problem, current, pool, executor, progress, f"round {len(selected) + 1}")
        for n in list(pool):
            if at_bound(round_fits[n].model, n):
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
        ahead: dict | None = dict(zip(order, run_tasks(problem, without_effect, [(n, current.model) for n in order], executor)))
        for name in order:
            without = ahead[name] if ahead is not None else without_effect(problem, name, current.model)
            d_held = problem.chi2(without.model, held) - problem.chi2(current.model, held)
            if without.bic - current.bic < BIC_THRESHOLD or (held.size and d_held < HELDOUT_CHI2_GAIN):
                selected.remove(name)
                dropped.append({"name": name, "delta_bic_when_removed": float(without.bic - current.bic),
                                "delta_heldout_chi2_when_removed": float(d_held)})
                current = without
                ahead = None  # later refits start from the reduced model
    twin_checks = []
    if selected:
        current = refit_fresh_material(problem, current, executor)
        current, selected, twin_checks, undecided = check_twins(problem, current, selected, allowed=names)
        confounded += undecided
    t3 = time.perf_counter()
    return Diagnosis(problem, baseline, candidates, selected, current, singles, confounded, dropped,
                     {"baseline_s": t1 - t0, "candidates_s": t2 - t1, "selection_s": t3 - t2}, twin_checks)
