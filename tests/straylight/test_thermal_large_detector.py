"""A small emitter under a large detector (CONTRACTS §7.1): the reverse method's rays leave uniform
points of the detector's front, so on a 2 m detector 1 mm from a 1 mm disk almost none of them meet
the disk (a fraction ~ A_disk / A_det = 2.5e-7) and the default run returned 0 +- 0 W. ``thermal``
now traces such a detector with the forward method and says so (straylight.thermal.run.reverse_suits),
and a reverse run that finds no emission at all is checked by the forward method.

Reference: an emitting disk (radius r1, Lambertian emissivity eps) seen by a coaxial parallel disk
(radius r2) at distance h receives P = eps B_band(T) pi A1 F12 (the plate's back faces away), with F12
from the disk-to-disk formula (Howell, *A Catalog of Radiation Heat Transfer Configuration Factors*,
C-40): R1 = r1/h, R2 = r2/h, X = 1 + (1 + R2^2) / R1^2, F12 = (X - sqrt(X^2 - 4 (R2/R1)^2)) / 2.
"""
from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from straylight.cli.main import main
from straylight.scene import load_scene
from straylight.thermal.model import thermal_scene
from straylight.thermal.planck import band_radiance_w_m2_sr
from straylight.thermal.run import MethodSwitchWarning, thermal
from tests.validation.thermal_scenes import view_factor_coaxial_disks  # Howell C-40 (PHYSICS 5)

SCENE = """
[material.front]
components = [{{type = "lambertian", rd = 0.3}}]
[material.back]
components = [{back}]

[[part]]
name = "plate"
surface = {{type = "plane", vertex_mm = [0.0, 0.0, 0.0], axis = [0.0, 0.0, 1.0], outer_radius_mm = 1.0}}
material = "front"
back_material = "back"
temperature_k = 400.0

[[part]]
name = "det"
surface = {{type = "plane", vertex_mm = [0.0, 0.0, {h_mm}], axis = [0.0, 0.0, {det_axis}], outer_radius_mm = {r_mm}}}
role = "detector"
"""


def expected_power_w(r2_mm, h_mm):
    """eps B_band(400 K, 9.9-10.1 um) pi A1 F12 for the r1 = 1 mm plate (eps = 1 - 0.3)."""
    area_m2 = np.pi * 1.0 ** 2 * 1e-6
    return 0.7 * band_radiance_w_m2_sr(9.9, 10.1, 400.0) * np.pi * area_m2 * view_factor_coaxial_disks(1.0, r2_mm, h_mm)


GREY = '{type = "lambertian", rd = 0.9}'
MIRROR = '{type = "specular", r = 1.0}'


def _scene(tmp_path, r_mm, h_mm=1.0, back=GREY, det_axis=-1.0):
    path = tmp_path / f"plate_{r_mm}_{h_mm}.toml"
    path.write_text(SCENE.format(r_mm=float(r_mm), h_mm=float(h_mm), back=back, det_axis=float(det_axis)))
    return path


def tolerance_w(power_w, stderr_w, rays, expect_w):
    """4 standard errors of the run (fixed seed), and at least 3 / rays of the value: where almost every
    forward ray reaches the detector (F within 1e-5 of 1 here) none may miss, so the run's stderr is 0
    while a fraction from N rays is only resolved to about 3 / N (the rule of three)."""
    return 4 * stderr_w + 3.0 / rays * expect_w


def _ts(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rs = load_scene(path, sources=False)
    return thermal_scene(rs.scene, rs.materials)


def test_reference_value_of_the_audit_geometry():
    """The closed form itself: 4.6376e-5 W for the 2000-mm detector at 1 mm (the value the audit expected)."""
    assert expected_power_w(2000.0, 1.0) == pytest.approx(4.6376e-5, rel=1e-4)
    assert view_factor_coaxial_disks(1.0, 1e6, 1.0) == pytest.approx(1.0, abs=1e-9)


@pytest.mark.parametrize("r_mm", [50.0, 500.0])
def test_small_emitter_under_a_large_detector_is_the_view_factor_within_4_sigma(tmp_path, r_mm):
    """Detector radius 50-500 mm: the reverse method gave 9e-5 to 5.8e-4 W with +-100 % error bars."""
    with pytest.warns(MethodSwitchWarning, match="traced with the forward method"):
        res = thermal(_ts(_scene(tmp_path, r_mm)), (9.9, 10.1), n_rays=20_000, seed=3)
    d = res.detectors["det"]
    expect = expected_power_w(r_mm, 1.0)
    assert d.power_w > 0  # the geometry couples
    assert d.method == "forward" and res.details()["detectors"]["det"]["method"] == "forward"
    assert abs(d.power_w - expect) <= tolerance_w(d.power_w, d.stderr_w, d.rays, expect), (d.power_w, d.stderr_w, expect)


def test_two_metre_detector_by_the_command(tmp_path, capsys):
    """The audit's scene: 2000-mm detector 1 mm over the plate; default method, --rays and --target-rel-error."""
    scene = _scene(tmp_path, 2000.0)
    expect = expected_power_w(2000.0, 1.0)
    for args in (["--rays", "20000"], ["--target-rel-error", "0.05"]):
        out = tmp_path / args[0].strip("-")
        assert main(["thermal", str(scene), "--band-um", "9.9", "10.1", *args, "--out", str(out)]) == 0
        err = capsys.readouterr().err
        assert "warning: detector 'det': the reverse method cannot serve it" in err
        det = json.loads((out / "thermal.json").read_text())["detectors"]["det"]
        details = json.loads((out / "thermal_details.json").read_text())
        assert det["power_w"] > 0
        rays = details["detectors"]["det"]["rays"]
        assert abs(det["power_w"] - expect) <= tolerance_w(det["power_w"], det["stderr_w"], rays, expect), (args, det)
        assert details["method"] == "forward" and "stopped" not in details
        assert any("forward method" in n for n in details["notes"])


def test_the_reverse_method_is_kept_where_it_serves(tmp_path):
    """A 1-mm detector over the same plate: the emitting area is larger than its front, no switch."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", MethodSwitchWarning)
        res = thermal(_ts(_scene(tmp_path, 1.0)), (9.9, 10.1), n_rays=20_000, seed=3)
    d = res.detectors["det"]
    expect = expected_power_w(1.0, 1.0)
    assert res.method == "reverse" and d.method == "reverse" and not res.notes
    assert d.power_w > 0
    assert abs(d.power_w - expect) <= 4 * d.stderr_w, (d.power_w, d.stderr_w, expect)


def test_a_reverse_zero_is_checked_by_the_forward_method(tmp_path):
    """A detector that sees only the plate's back, whose material reflects everything (epsilon 0): the
    reverse rays find no emission, the forward method confirms the zero, and the result says so."""
    path = _scene(tmp_path, 1.0, h_mm=-1.0, back=MIRROR, det_axis=1.0)
    with pytest.warns(MethodSwitchWarning, match="found no emission"):
        res = thermal(_ts(path), (9.9, 10.1), n_rays=2_000, seed=1)
    d = res.detectors["det"]
    assert d.power_w == 0.0 and d.method == "forward"
    assert any("found no emission in 2000 rays" in n for n in res.notes)
