"""The OUT.json document of CONTRACTS 4.1."""
from __future__ import annotations

import numpy as np

from rig.diagnose.candidates import BIC_THRESHOLD
from rig.diagnose.heldout import HELDOUT_CHI2_GAIN
from rig.diagnose.regions import region_table

GAP_METRIC = "rms_log10"


def to_json(d) -> dict:
    """The OUT.json document of CONTRACTS §4.1 (plus extra fields)."""
    p = d.problem
    held, train = p.held_idx, p.train_idx
    base_rows = region_table(p, d.baseline.model)
    final_rows = region_table(p, d.final.model)
    # blame: per region, the selected effect whose single fit lowers that region's gap most
    single_rows = {n: region_table(p, d.single_fits[n].model) for n in d.selected if n in d.single_fits}
    regions = []
    for i, row in enumerate(base_rows):
        row = dict(row)
        row["gap_final"] = final_rows[i]["gap"]
        row["bias_final"] = final_rows[i]["bias"]
        blamed, best = None, row["gap"]
        for n in single_rows:
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
        "twin_checks": d.twin_checks,
        "dropped_effects": d.dropped,
        "final": {"heldout_gap": p.gap(d.final.model, held), "train_gap": p.gap(d.final.model, train),
                  "bic": d.final.bic, "material": d.final.model.material(p.wavelength_nm).to_dict()},
        "noise_level": {"heldout_gap": noise_held, "train_gap": noise_train,
                        "meaning": "the gap a perfect model would leave: RMS of std/(sqrt(n) brdf ln 10) on the same points"},
        "thresholds": {"delta_bic": -BIC_THRESHOLD, "delta_heldout_chi2": -HELDOUT_CHI2_GAIN},
        "timings_s": d.timings,
    }
