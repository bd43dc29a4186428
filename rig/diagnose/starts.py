"""Starting points of the fits: materials from the data, effect parameters from each effect's
``fit_space`` (and its ``starts_from_data``)."""
from __future__ import annotations

import math

import numpy as np

from rig.diagnose.params import Model
from rig.diagnose.problem import Problem
from rig.effects import effect_types


def material_starts(problem: Problem, n_lobes: int):
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


def rescale_lobes(problem: Problem, model: Model) -> Model:
    """Scale all lobe sigmas so the model's highest training reading matches the data's
    (BRDF ~ sigma^2): a cheap first step that keeps the optimiser out of flat regions."""
    idx = problem.train_idx
    sim = problem.predict(model, idx)
    ratio = float(np.max(problem.y[idx]) / max(np.max(sim), 1e-300))
    vals = dict(model.values)
    for k in range(model.n_lobes):
        vals[("material", f"sigma{k}_nm")] = float(np.clip(vals[("material", f"sigma{k}_nm")] * math.sqrt(ratio), 1e-3, 300))
    return Model(model.n_lobes, vals, model.effects)


def effect_starts(problem: Problem, name: str):
    """Starting values for an effect's parameters: the ``fit_space`` starts, with ``None`` filled by
    the effect's own ``starts_from_data`` (or the middle of the range); at most three combinations."""
    cls = effect_types()[name]
    idx = problem.train_idx
    signal = problem.y[idx] * np.cos(problem.theta_r[idx])
    data = cls.starts_from_data(signal) if hasattr(cls, "starts_from_data") else {}
    combos: list[dict[str, float]] = [{}]
    for p, (lo, hi, scale, starts) in cls.fit_space.items():
        values = []
        for s in starts:
            if s is not None:
                values.append(s)
            elif p in data:
                values += list(data[p])
            else:
                values.append(0.5 * (lo + hi))
        values = [float(np.clip(v, lo, hi)) for v in values]
        combos = [dict(c, **{p: v}) for c in combos for v in values]
    return combos[:3]
