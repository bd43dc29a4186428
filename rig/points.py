"""Scan points: a point and its identity (the key a CSV row, a plan and ``--resume`` agree on),
the seed paper's grid, the one paper plan of the project (``straylight rig scan --plan
paper`` measures it), and plans as arrays (:func:`paper_plan`: that grid with a backscatter wing;
:func:`score_plan`, :func:`compact_plan`, :func:`make_plan`), the plans of :mod:`rig.synth`'s
synthetic scans.

The paper plan (seed paper section 3): incidence 10, 30, 40, 70, 80 deg; s then p; 3 readings
per point. Viewing angles, with ``d = theta_r - theta_i`` (zones chosen here; the paper gives
only the step sizes):

| zone | abs(d) (deg) | step (deg) | points per incidence |
|---|---|---|---|
| core | 0 .. 0.5 | 0.05 | 21 |
| shoulder | 0.5 .. 2.5 | 0.2 | 20 (0.7, 0.9, .. 2.5 each side) |
| near | 2.5 .. 5 | 0.5 | 10 (3.0, 3.5, .. 5.0 each side) |
| wing | > 5 | 5 | d = +-10, +-15, .. |

all clipped to ``0 <= theta_r <= 85`` deg on the specular side (phi_r = 0).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

PAPER_THETA_I_DEG = (10.0, 30.0, 40.0, 70.0, 80.0)
PAPER_POLARIZATIONS = ("s", "p")
PAPER_N_READINGS = 3
THETA_R_MAX_DEG = 85.0
#: (|d| upper edge, step) of the paper grid's zones around specular, deg
PAPER_ZONES_DEG = ((0.5, 0.05), (2.5, 0.2), (5.0, 0.5))
WING_STEP_DEG = 5.0


class Point(NamedTuple):
    theta_i_deg: float
    polarization: str
    theta_r_deg: float
    phi_r_deg: float = 0.0


def point_key(theta_i_deg, polarization, theta_r_deg, phi_r_deg) -> tuple:
    """Hashable identity of a point, angles rounded to 1e-6 deg (resume matches on it)."""
    return (round(float(theta_i_deg), 6), str(polarization), round(float(theta_r_deg), 6),
            round(float(phi_r_deg) % 360.0, 6))


def paper_theta_r_deg(theta_i_deg: float, theta_r_max_deg: float = THETA_R_MAX_DEG) -> np.ndarray:
    """The paper grid's viewing angles for one incidence (module table), ascending, deg."""
    offsets = [0.0]
    lo = 0.0
    for hi, step in PAPER_ZONES_DEG:
        n = int(round((hi - lo) / step))
        offsets += [lo + step * k for k in range(1, n + 1)]
        lo = hi
    k = 2
    while WING_STEP_DEG * k <= 90.0:
        offsets.append(WING_STEP_DEG * k)
        k += 1
    d = np.round(np.array(offsets), 6)
    theta_r = np.concatenate([theta_i_deg - d[1:], [theta_i_deg], theta_i_deg + d[1:]])
    theta_r = np.round(theta_r, 6)
    keep = (theta_r >= 0.0) & (theta_r <= theta_r_max_deg)
    return np.unique(theta_r[keep])


def paper_points(theta_i_deg=PAPER_THETA_I_DEG, polarizations=PAPER_POLARIZATIONS,
                 theta_r_max_deg: float = THETA_R_MAX_DEG) -> list[Point]:
    """The seed paper's scan as points, polarization-major."""
    return [Point(float(ti), pol, float(tr), 0.0)
            for pol in polarizations for ti in theta_i_deg
            for tr in paper_theta_r_deg(float(ti), theta_r_max_deg)]


def paper_viewing_deg(theta_i_deg: float, *, backscatter_step_deg: float | None = None, retro_gap_deg: float = 3.0,
                      theta_r_max_deg: float = THETA_R_MAX_DEG) -> np.ndarray:
    """Signed in-plane viewing angles of the paper grid (negative: the backscatter side,
    ``phi_r = 180``): :func:`paper_theta_r_deg`, plus, with ``backscatter_step_deg``, the
    backscatter side every that many degrees, leaving out ``retro_gap_deg`` around the incident
    beam (the detector head would block it). Ascending."""
    tr = paper_theta_r_deg(theta_i_deg, theta_r_max_deg)
    if backscatter_step_deg:
        back = -np.arange(backscatter_step_deg, theta_r_max_deg + 1e-9, backscatter_step_deg)
        back = back[np.abs(back + theta_i_deg) >= retro_gap_deg]
        tr = np.concatenate([back, tr])
    return np.unique(np.round(tr, 6))


# ----------------------------------------------------------------------------- plans as arrays
# (theta_i_deg, theta_r_deg signed, polarization) arrays: the synthetic scans' plans (rig.synth)

RETRO_GAP_DEG = 3.0  # the detector cannot view within this of the incident beam


def _viewing_grid(theta_i_deg, steps):
    """Signed viewing angles: ``steps`` is a list of (half_range_deg, step_deg) around
    specular, finest first, then the off-specular grid; retro and |theta| > 85 removed."""
    pts = []
    for half, step in steps[:-1]:
        k = int(round(half / step))
        pts.append(theta_i_deg + step * np.arange(-k, k + 1))
    off_step = steps[-1][1]
    pts.append(np.arange(-THETA_R_MAX_DEG, THETA_R_MAX_DEG + 1e-9, off_step))
    tr = np.unique(np.round(np.concatenate(pts), 6))
    keep = (np.abs(tr) <= THETA_R_MAX_DEG) & (np.abs(tr + theta_i_deg) >= RETRO_GAP_DEG)
    return tr[keep]


def make_plan(theta_i_deg=PAPER_THETA_I_DEG, polarizations=("s", "p"), steps=None):
    """(theta_i_deg, theta_r_deg (signed), polarization) arrays for a scan.

    ``steps``: [(half_range_deg, step_deg), ..., (None, off_step_deg)], finest first.
    """
    if steps is None:
        steps = [(0.5, 0.05), (2.0, 0.2), (5.0, 0.5), (None, 5.0)]
    return _plan_arrays(theta_i_deg, polarizations, lambda ti: _viewing_grid(ti, steps))


def paper_plan(theta_i_deg=PAPER_THETA_I_DEG, polarizations=("s", "p")):
    """The seed paper's plan, the project's one (:func:`paper_viewing_deg`: 0.05 deg
    steps within 0.5 deg of specular, 0.2 to 2.5 deg, 0.5 to 5 deg, 5 deg beyond; specular side
    0..85 deg), with the backscatter side added every 5 deg (``RETRO_GAP_DEG`` left out around the
    beam), ~90 points per curve."""
    return _plan_arrays(theta_i_deg, polarizations, lambda ti: paper_viewing_deg(
        ti, backscatter_step_deg=5.0, retro_gap_deg=RETRO_GAP_DEG, theta_r_max_deg=THETA_R_MAX_DEG))


def _plan_arrays(theta_i_deg, polarizations, viewing_grid):
    """(theta_i_deg, theta_r_deg, polarization) arrays: ``viewing_grid(theta_i_deg)`` per incidence,
    repeated for each polarization."""
    ti_all, tr_all, pol_all = [], [], []
    for ti in np.atleast_1d(np.asarray(theta_i_deg, float)):
        if not 0.0 <= ti < 90.0:
            raise ValueError(f"theta_i_deg: {ti} outside [0, 90)")
        tr = viewing_grid(float(ti))
        for pol in polarizations:
            if pol not in ("s", "p", "u"):
                raise ValueError(f"polarizations: unknown {pol!r}")
            ti_all.append(np.full(tr.shape, ti))
            tr_all.append(tr)
            pol_all.append(np.full(tr.shape, pol))
    return np.concatenate(ti_all), np.concatenate(tr_all), np.concatenate(pol_all)


#: The incidences of the synthetic score scans: six, two of them (40, 80) held out by default.
SCORE_INCIDENCES_DEG = (10.0, 25.0, 40.0, 55.0, 70.0, 80.0)


def score_plan(theta_i_deg=SCORE_INCIDENCES_DEG, polarizations=("s", "p")):
    """The score scans' plan: :func:`paper_plan` (the paper's grid with a backscatter wing) at six
    incidences. The paper's fine steps resolve a blurred core (wide slit, diverging beam) that
    0.1 / 0.5 deg steps see only as a wider lobe."""
    return paper_plan(theta_i_deg, polarizations)


def compact_plan(theta_i_deg=SCORE_INCIDENCES_DEG, polarizations=("s", "p")):
    """~60 points per curve: 0.1 deg within 0.5 deg, 0.5 deg to 3 deg, 5 deg beyond."""
    return make_plan(theta_i_deg, polarizations, steps=[(0.5, 0.1), (3.0, 0.5), (None, 5.0)])
