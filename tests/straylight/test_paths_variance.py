"""The path report on the variance: each group's share of the detector estimate's
variance, and the "family" grouping that merges numbered parts (vane_1 .. vane_N -> vane).

Records are built by hand so the shares are known exactly: a group where every ray gives the same
amount has zero variance; a group where one ray in N gives everything carries the variance."""
import numpy as np

from straylight.analyses.paths_report import path_report
from straylight.paths import KIND_SCATTER, PathRecords, mix_key

NAMES = ("vane_1", "vane_2", "wall", "det")


def _records(rows, n_rays):
    """rows: (ray, part names..., power)."""
    ray, power, keys, events = [], [], [], []
    for r, parts, p in rows:
        codes = [NAMES.index(x) * 4 + KIND_SCATTER for x in parts]
        k = np.zeros(1, dtype=np.uint64)
        for c in codes:
            k = mix_key(k, c)
        ev = np.full(4, -1, dtype=np.int16)
        ev[:len(codes)] = codes
        ray.append(r), power.append(p), keys.append(k[0]), events.append(ev)
    return PathRecords(np.array(ray, np.int64), np.full(len(ray), 3, np.int16), np.array(power, float),
                       np.array([len(p) for _, p, _ in rows], np.int16), np.array(keys, np.uint64),
                       np.array(events), NAMES, n_rays)


def test_variance_share_goes_to_the_rare_heavy_group():
    n = 1000
    rows = [(r, ("wall",), 1e-3) for r in range(n)]  # every ray the same: no variance
    rows.append((7, ("vane_1",), 0.5))  # one ray carries a heavy path
    rep = path_report(_records(rows, n), detector="det")
    share = {r.label: r.variance_fraction for r in rep.rows}
    assert share["source -> vane_1 -> det"] > 0.99
    assert share["source -> wall -> det"] < 1e-12
    # the power ranking says the opposite: the wall carries two thirds of the power
    assert rep.rows[0].label == "source -> wall -> det"


def test_family_grouping_merges_numbered_parts():
    n = 10
    rows = [(0, ("vane_1",), 1.0), (1, ("vane_2",), 2.0), (2, ("wall", "vane_2"), 4.0)]
    rep = path_report(_records(rows, n), detector="det", group_by="family")
    power = {r.label: r.power_w for r in rep.rows}
    assert power == {"source -> vane -> det": 3.0, "source -> wall -> vane -> det": 4.0}
    assert "| share of the variance |" in rep.markdown()
