"""Scan regions of the diagnosis (CONTRACTS 4.1): where each point sits relative to specular,
and the gap and bias per (region, incidence, polarization).

``specular_core`` (|theta_r - theta_i| <= 0.5 deg in the plane), ``shoulder`` (0.5..5 deg),
``wing`` (beyond), and where present ``grazing`` (viewing beyond 75 deg, outside core and
shoulder) and ``near_retro`` (backscatter side within 10 deg of the incident beam).
"""
from __future__ import annotations

import numpy as np

CORE_DEG, SHOULDER_DEG, GRAZING_DEG, RETRO_DEG = 0.5, 5.0, 75.0, 10.0
REGION_ORDER = ("specular_core", "shoulder", "wing", "grazing", "near_retro")


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


def region_table(problem, model) -> list:
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
