"""``exchange`` emits from every side that absorbs (CONTRACTS §7): a one-sided part (an analytic
surface, an open mesh) from both sides, each with its side's emissivity. It emitted from fronts only,
so a plate's back, which absorbs, never emitted: D(plate -> absorber behind it) was 0 while
D(absorber -> plate) was 0.017, and reciprocity eps_i A_i D_ij = eps_j A_j D_ji failed.

References: reciprocity (Mahan, *Radiation Heat Transfer: A Statistical Approach*, 2002, ch. 5) and,
for two black one-sided disks, the disk-to-disk view factor (Howell's catalogue C-40): a's front sends
F_ab of its power to b, its back (as much power) none, so D_ab = F_ab / 2 with eps_a A_a = 2 A_disk.
Tolerances: 4 standard errors of the run (fixed seed).
"""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from straylight.scene import load_scene
from straylight.thermal.exchange import exchange
from straylight.thermal.model import thermal_scene
from tests.validation.thermal_scenes import view_factor_coaxial_disks  # Howell C-40 (PHYSICS 5)

PLATE_BETWEEN_ABSORBERS = """
[material.f]
components = [{type = "lambertian", rd = 0.3}]
[material.b]
components = [{type = "lambertian", rd = 0.9}]

[[part]]
name = "plate"
surface = {type = "plane", vertex_mm = [0.0, 0.0, 0.0], axis = [0.0, 0.0, 1.0], outer_radius_mm = 10.0}
material = "f"
back_material = "b"

[[part]]
name = "absF"
surface = {type = "plane", vertex_mm = [0.0, 0.0, 20.0], axis = [0.0, 0.0, -1.0], outer_radius_mm = 10.0}
role = "absorber"

[[part]]
name = "absB"
surface = {type = "plane", vertex_mm = [0.0, 0.0, -20.0], axis = [0.0, 0.0, 1.0], outer_radius_mm = 10.0}
role = "absorber"
"""

TWO_BLACK_DISKS = """
[[part]]
name = "a"
surface = {type = "plane", vertex_mm = [0.0, 0.0, 0.0], axis = [0.0, 0.0, 1.0], outer_radius_mm = 10.0}
role = "absorber"

[[part]]
name = "b"
surface = {type = "plane", vertex_mm = [0.0, 0.0, 50.0], axis = [0.0, 0.0, -1.0], outer_radius_mm = 20.0}
role = "absorber"
"""


def _ts(tmp_path, text):
    path = tmp_path / "scene.toml"
    path.write_text(text)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rs = load_scene(path, sources=False)
    return thermal_scene(rs.scene, rs.materials)


@pytest.fixture(scope="module")
def plate_run(tmp_path_factory):
    ts = _ts(tmp_path_factory.mktemp("plate"), PLATE_BETWEEN_ABSORBERS)
    return exchange(ts, (8.0, 12.0), n_rays=60_000, seed=2)


def test_plate_back_emits_and_reciprocity_holds(plate_run):
    res = plate_run
    i = {n: k for k, n in enumerate(res.names)}
    p, f, b = i["plate"], i["absF"], i["absB"]
    assert res.d[p, b] > 0  # the back emits toward the absorber behind it (was exactly 0)
    g = res.couplings_m2()  # eps_i A_i D_ij, m^2
    ge = (res.emissivity * res.area_mm2 * 1e-6)[:, None] * res.stderr
    for j in (f, b):
        sig = np.hypot(ge[p, j], ge[j, p])
        assert g[p, j] > 0 and g[j, p] > 0
        assert abs(g[p, j] - g[j, p]) <= 4 * sig, (res.names[j], g[p, j], g[j, p], sig)
    # the two absorbers see each other only past the plate's edge, through nothing: no coupling either way
    assert res.d[f, b] == 0 and res.d[b, f] == 0


def test_emitting_area_and_band_emissivity_count_both_sides(plate_run):
    res = plate_run
    area = np.pi * 10.0 ** 2
    np.testing.assert_allclose(res.area_mm2, 2 * area, rtol=1e-12)  # every part here is one-sided
    p = res.names.index("plate")
    # eps A = (eps_front + eps_back) A_disk: the mean of 0.7 and 0.1 over twice the disk
    assert res.emissivity[p] == pytest.approx((0.7 + 0.1) / 2, abs=1e-6)
    assert res.emissivity[res.names.index("absF")] == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(res.d.sum(axis=1) + res.escaped + res.truncated, 1.0, atol=1e-12)


def test_black_one_sided_disks_d_is_half_the_view_factor(tmp_path):
    res = exchange(_ts(tmp_path, TWO_BLACK_DISKS), (8.0, 12.0), n_rays=60_000, seed=4)
    f_ab = view_factor_coaxial_disks(10.0, 20.0, 50.0)
    f_ba = f_ab * 100.0 / 400.0
    assert res.d[0, 1] > 0
    assert abs(res.d[0, 1] - f_ab / 2) <= 4 * res.stderr[0, 1], (res.d[0, 1], f_ab / 2, res.stderr[0, 1])
    assert abs(res.d[1, 0] - f_ba / 2) <= 4 * res.stderr[1, 0], (res.d[1, 0], f_ba / 2, res.stderr[1, 0])
    # the couplings are the single-sided ones: eps A D = A_disk F (reciprocity A_a F_ab = A_b F_ba)
    assert res.couplings_m2()[0, 1] == pytest.approx(np.pi * 100e-6 * f_ab, rel=4 * res.stderr[0, 1] / res.d[0, 1])
