"""Distribution factors (straylight.thermal.exchange; CONTRACTS §7.2) against closed
forms: the coaxial-disk view factor (PHYSICS §5) and, in a closed enclosure, rows summing to 1 and
reciprocity eps_i A_i D_ij = eps_j A_j D_ji. Every absorbing side emits (CONTRACTS §7): a one-sided
part (an analytic surface, an open mesh) from both sides. Tolerances: 3 standard errors of the run
(fixed seed)."""
import json
import warnings

import numpy as np
import pytest

from straylight.cli.main import main
from straylight.scene import load_scene
from straylight.thermal.exchange import exchange
from straylight.thermal.model import thermal_scene
from tests.validation.thermal_scenes import (
    part,
    plane,
    view_factor_coaxial_disks,
    write_box,
    write_scene,
)


def test_black_coaxial_disks_d12_is_half_the_view_factor(tmp_path):
    """One-sided black disks emit from both sides: the back's half goes nowhere, D_12 = F_12 / 2, and the
    coupling eps_1 A_1 D_12 (A_1 both sides) is A_disk F_12."""
    text = part("a", role="absorber", surface=plane((0, 0, 0), (0, 0, 1), 10.0))
    text += part("b", role="absorber", surface=plane((0, 0, 50), (0, 0, -1), 20.0))
    path = write_scene(tmp_path, text)
    out = tmp_path / "out"
    assert main(["exchange", str(path), "--band-um", "8", "12", "--rays", "60000", "--seed", "4",
                 "--out", str(out)]) == 0
    doc = json.loads((out / "exchange.json").read_text())
    assert set(doc) == {"band_um", "parts", "distribution_factors", "stderr", "escaped"}
    d, e = np.array(doc["distribution_factors"]), np.array(doc["stderr"])
    f12 = view_factor_coaxial_disks(10, 20, 50)  # 0.1339 for 0.1 / 0.2 / 0.5 (PHYSICS §5)
    f21 = f12 * 100 / 400
    assert abs(d[0, 1] - f12 / 2) <= 3 * e[0, 1] and abs(d[1, 0] - f21 / 2) <= 3 * e[1, 0]
    assert d[0, 0] == 0 and d[1, 1] == 0
    assert np.allclose(d.sum(axis=1) + doc["escaped"], 1.0, atol=1e-12)
    assert [p["emissivity"] for p in doc["parts"]] == pytest.approx([1.0, 1.0], abs=1e-12)
    assert doc["parts"][0]["area_mm2"] == pytest.approx(2 * np.pi * 100)  # both sides emit
    rows = (out / "couplings.csv").read_text().splitlines()
    assert rows[0] == "part,a,b" and float(rows[1].split(",")[2]) == pytest.approx(2 * np.pi * 100e-6 * d[0, 1], rel=1e-6)


def test_closed_enclosure_rows_sum_to_one_and_reciprocity(tmp_path):
    meshes = write_box(tmp_path)
    mats = {"floor": "black", "ceiling": "mirror", "wx0": "glossy", "wx1": "grey", "wy0": "grey", "wy1": "black"}
    text = "".join(part(n, mats[n], 300.0, mesh=m) for n, m in meshes.items())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rs = load_scene(write_scene(tmp_path, text), sources=False)
    res = exchange(thermal_scene(rs.scene, rs.materials), (8, 12), n_rays=30_000, seed=7)
    # the walls are open sheets: their outsides emit too (CONTRACTS §7), into nothing: half of each row
    # escapes (a ray may also slip out through a seam: the 1e-3)
    assert np.allclose(res.escaped, 0.5, atol=1e-3) and np.all(res.escaped >= 0.5 - 1e-12)
    assert np.allclose(res.d.sum(axis=1) + res.escaped, 1.0, atol=1e-12)
    g = res.couplings_m2()
    ge = (res.emissivity * res.area_mm2 * 1e-6)[:, None] * res.stderr
    n = len(res.names)
    checked = 0
    for i in range(n):
        for j in range(i + 1, n):
            sig = np.hypot(ge[i, j], ge[j, i])
            assert abs(g[i, j] - g[j, i]) <= 3 * sig + 1e-12, (res.names[i], res.names[j], g[i, j], g[j, i], sig)
            checked += g[i, j] > 0
    assert checked >= 12
    # the specular mirror absorbs little: eps_h = 1 - 0.9
    assert res.emissivity[res.names.index("ceiling")] == pytest.approx(0.1, abs=1e-9)
