"""PST sweep: geometric transmission of a black tube, cut-off, NEE vs plain walk, outputs."""
import json
import math

import numpy as np
import pytest
from scipy import integrate

from materials import Lambertian
from straylight.analyses.builtin import tube_setup
from straylight.analyses.types import Setup
from straylight.analyses.pst import geometric_direct_ratio, part_area_mm2, pst_sweep


@pytest.fixture(scope="module")
def empty_tube():
    """The reference tube without vanes: wall r 50, 300 mm; end plate hole and detector r 35 at z = 0."""
    return tube_setup(material=Lambertian(rd=0.0), vane_count=0)


def with_material(setup, model):
    return Setup(setup.scene, {"coating": model}, setup.beam, setup.entrance, setup.detector, setup.description)


def lens_area_quad(big, small, s):
    """Overlap area of two disks (radii big, small; centres s apart) by scipy quadrature of 2 min(h1, h2)."""
    def chord(x):
        h1 = math.sqrt(max(0.0, big**2 - x**2))
        h2 = math.sqrt(max(0.0, small**2 - (x - s) ** 2))
        return 2.0 * min(h1, h2)

    lo, hi = max(-big, s - small), min(big, s + small)
    if hi <= lo:
        return 0.0
    return integrate.quad(chord, lo, hi, points=[lo, hi], limit=200, epsabs=1e-9)[0]


def test_geometric_direct_ratio_matches_benchmark_table():
    """BENCHMARK.md: direct(a) through the top vane's r = 35 hole (top face z = 280.5) onto the
    r = 35 detector: 0.49000, 0.27584, 0.08927, 0, 0 at 0, 5, 10, 20, 30 deg (of the r = 50 entrance)."""
    a = np.radians([0, 5, 10, 20, 30])
    got = geometric_direct_ratio(a, 35.0, 35.0, 280.5) * (35.0 / 50.0) ** 2
    np.testing.assert_allclose(got, [0.49000, 0.27584, 0.08927, 0.0, 0.0], atol=6e-6)


@pytest.mark.parametrize("computed", [False, True], ids=["walk", "direct_area"])
def test_black_empty_tube_gives_geometric_transmission_and_zero_past_cutoff(empty_tube, computed):
    """Black walls (rd = 0): ratio(a) = lens area(entrance r 50 shifted by 300 tan a, detector r_d) / (pi 50^2).

    Expected values come from scipy quadrature of the disk overlap, with r_d the radius of
    a disk of the tessellated detector's area (the mesh is an inscribed polygon, 0.1 % smaller
    in area). Past the cut-off atan(85 / 300) = 15.8 deg nothing can reach the detector
    without scattering, and nothing scatters: the ratio must be exactly 0. The walk alone (``direct_area``
    off) counts the light that comes straight with its binomial error (4 sigma); the default set computes it
    (straylight.engine.direct_area, on the tessellated parts: within 2e-3 of the disks' overlap, with an error
    bar of round-off only, every ray carrying the same share).
    """
    from dataclasses import replace

    from straylight.analyses.estimators import estimator_options

    opts = estimator_options("default", materials=empty_tube.materials)
    if not computed:
        opts = replace(opts, estimator=replace(opts.estimator, direct_area=False))
    r_det = math.sqrt(part_area_mm2(empty_tube.scene, "detector") / math.pi)
    angles_deg = np.array([0.0, 5.0, 10.0, 20.0])
    res = pst_sweep(empty_tube, np.radians(angles_deg), n_rays=60_000, seed=3, options=opts)
    for a_deg, got, se in zip(angles_deg[:3], res.entrance_ratio[:3], res.entrance_ratio_stderr[:3]):
        expected = lens_area_quad(50.0, r_det, 300.0 * math.tan(math.radians(a_deg))) / (math.pi * 50.0**2)
        if computed:
            assert abs(got - expected) < 2e-3 * expected and 0 <= se < 1e-9 * got, (a_deg, got, expected, se)
            continue
        assert got > 0 and se > 0  # sanity: the geometry couples
        # binomial counting error of the run itself; 4 sigma
        assert abs(got - expected) < 4 * se, (a_deg, got, expected, se)
    assert res.entrance_ratio[3] == 0.0
    # PST (irradiance normalisation) = ratio * entrance area * cos a / detector area
    area = part_area_mm2(empty_tube.scene, "detector")
    np.testing.assert_allclose(res.pst, res.entrance_ratio * math.pi * 50.0**2 * np.cos(np.radians(angles_deg)) / area,
                               rtol=1e-12)


def test_nee_agrees_with_plain_walk_on_scattered_light(empty_tube):
    """At 20 deg (past the cut-off) only scattered light arrives; with rd = 0.9 walls there is plenty.
    Next-event estimation and the plain random walk estimate the same expectation:
    their difference must lie within 4 combined standard errors, and NEE must be more precise."""
    setup = with_material(empty_tube, Lambertian(rd=0.9))
    nee = pst_sweep(setup, np.radians([20.0]), n_rays=40_000, seed=5, nee=True)
    plain = pst_sweep(setup, np.radians([20.0]), n_rays=40_000, seed=6, nee=False)
    assert nee.entrance_ratio[0] > 0 and plain.entrance_ratio[0] > 0
    combined = math.hypot(nee.entrance_ratio_stderr[0], plain.entrance_ratio_stderr[0])
    assert abs(nee.entrance_ratio[0] - plain.entrance_ratio[0]) < 4 * combined
    assert nee.entrance_ratio_stderr[0] < plain.entrance_ratio_stderr[0]


def test_same_seed_same_numbers_and_outputs(empty_tube, tmp_path):
    setup = with_material(empty_tube, Lambertian(rd=0.5))
    a = pst_sweep(setup, np.radians([0.0, 25.0]), n_rays=5_000, seed=11)
    b = pst_sweep(setup, np.radians([0.0, 25.0]), n_rays=5_000, seed=11)
    np.testing.assert_array_equal(a.pst, b.pst)
    assert a.pst[1] > 0  # scattered light at 25 deg
    a.write_csv(tmp_path / "pst.csv")
    a.write_json(tmp_path / "pst.json")
    a.plot(tmp_path / "pst.png")
    header = (tmp_path / "pst.csv").read_text().splitlines()[0]
    assert header.startswith("off_axis_deg,azimuth_deg,pst,pst_stderr,entrance_ratio")
    doc = json.loads((tmp_path / "pst.json").read_text())
    assert [p["off_axis_deg"] for p in doc["points"]] == [0.0, 25.0]
    assert (tmp_path / "pst.png").stat().st_size > 10_000


def test_beam_not_covering_entrance_is_a_clear_error(empty_tube):
    from straylight.analyses.types import Beam, Entrance

    beam = Beam(center_mm=(0, 0, 310), axis=(0, 0, -1), radius_mm=52.0)
    with pytest.raises(ValueError, match="does not cover the entrance"):
        Entrance(center_mm=(0, 0, 300), radius_mm=50.0).power_w(beam, math.radians(30))


def test_azimuth_does_not_matter_for_an_axisymmetric_tube(empty_tube):
    """Turning the tilt about the tube axis (azimuth 0 vs 90 deg) must give the same PST within errors
    (rotational symmetry; the tessellation breaks it only at the 0.1 % level)."""
    setup = with_material(empty_tube, Lambertian(rd=0.5))
    res = pst_sweep(setup, np.radians([25.0]), np.radians([0.0, 90.0]), n_rays=20_000, seed=8)
    assert list(res.azimuth_deg) == [0.0, 90.0]
    assert res.pst[0] > 0 and res.pst[1] > 0
    assert abs(res.pst[0] - res.pst[1]) < 4 * math.hypot(*res.pst_stderr)
    d0, d90 = setup.beam.direction(math.radians(25), 0.0), setup.beam.direction(math.radians(25), math.pi / 2)
    np.testing.assert_allclose(d0, [math.sin(math.radians(25)), 0, -math.cos(math.radians(25))], atol=1e-15)
    np.testing.assert_allclose(d90, [0, math.sin(math.radians(25)), -math.cos(math.radians(25))], atol=1e-15)


@pytest.mark.parametrize("flag, value, words", [("--azimuths-deg", "nan", "--azimuths-deg must be finite numbers"),
                                                ("--angles-deg", "95", "--angles-deg must be in (-90, 90) deg")])
def test_a_bad_angle_is_refused_in_one_line_naming_it(flag, value, words, tmp_path, capsys):
    from straylight.cli.main import main

    args = ["pst", "--builtin", "tube", "--rays", "1000", "--out", str(tmp_path / "o")]
    args += ["--angles-deg", "5", flag, value] if flag == "--azimuths-deg" else [flag, value]
    assert main(args) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and words in err[0], err
