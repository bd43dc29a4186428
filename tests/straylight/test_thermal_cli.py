"""``straylight thermal`` writes CONTRACTS §7.1's thermal.json."""
import json

import numpy as np
import pytest

from straylight.cli.main import main
from straylight.thermal.planck import band_radiance_w_m2_sr
from tests.validation.thermal_scenes import (
    part,
    plane,
    view_factor_coaxial_disks,
    write_scene,
)


@pytest.fixture
def two_disks(tmp_path):
    text = part("focal_plane", role="detector", temperature_k=77.0, surface=plane((0, 0, 0), (0, 0, 1), 5.0))
    text += part("baffle", "black", 300.0, surface=plane((0, 0, 30), (0, 0, -1), 20.0))
    return write_scene(tmp_path, text)


def test_thermal_json_keys_and_value(two_disks, tmp_path):
    out = tmp_path / "out"
    assert main(["thermal", str(two_disks), "--band-um", "8", "12", "--rays", "6000", "--seed", "1",
                 "--out", str(out)]) == 0
    doc = json.loads((out / "thermal.json").read_text())
    assert doc["band_um"] == [8.0, 12.0] and doc["rays"] == 6000 and doc["seed"] == 1
    det = doc["detectors"]["focal_plane"]
    assert set(det) >= {"power_w", "stderr_w", "irradiance_w_m2", "by_part"}
    assert set(det["by_part"]) == {"baffle", "focal_plane"}
    assert sum(v["power_w"] for v in det["by_part"].values()) == pytest.approx(det["power_w"], rel=1e-12)
    # black disk, emissivity 0.95 (Lambertian rd = 0.05): pi B eps A F; the detector sees only the disk
    expect = np.pi * band_radiance_w_m2_sr(8, 12, 300) * 0.95 * np.pi * 400e-6 * view_factor_coaxial_disks(20, 5, 30)
    assert abs(det["power_w"] - expect) <= 3 * det["stderr_w"] + 2e-3 * expect
    assert det["irradiance_w_m2"] == pytest.approx(det["power_w"] / (np.pi * 25e-6))


def test_same_seed_same_numbers(two_disks, tmp_path):
    """Twice in this process, then on 2 threads (--workers 2): the same numbers (the engine's chunk streams)."""
    docs = []
    for k, where in enumerate(([], [], ["--workers", "2"])):
        out = tmp_path / f"o{k}"
        assert main(["thermal", str(two_disks), "--band-um", "8", "12", "--rays", "3000", *where, "--out", str(out)]) == 0
        docs.append(json.loads((out / "thermal.json").read_text())["detectors"])
    assert docs[0]["focal_plane"]["power_w"] > 0
    assert docs[0] == docs[1] == docs[2]


def test_target_rel_error(two_disks, tmp_path):
    out = tmp_path / "t"
    assert main(["thermal", str(two_disks), "--band-um", "8", "12", "--target-rel-error", "0.005",
                 "--out", str(out)]) == 0
    det = json.loads((out / "thermal.json").read_text())["detectors"]["focal_plane"]
    assert 0 < det["stderr_w"] <= 0.005 * det["power_w"]


@pytest.mark.parametrize("args,msg", [(["--band-um", "12", "8", "--rays", "10"], "band-um"),
                                      (["--band-um", "8", "12", "--rays", "1"], "rays")])
def test_bad_input_is_one_line(two_disks, tmp_path, capsys, args, msg):
    assert main(["thermal", str(two_disks), *args, "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and msg in err[0]


def test_bad_temperature_names_the_part(tmp_path, capsys):
    path = write_scene(tmp_path, part("d", role="detector", surface=plane((0, 0, 0), (0, 0, 1), 5.0))
                       + '[[part]]\nname = "hot"\nsurface = ' + plane((0, 0, 9), (0, 0, -1), 5.0)
                       + '\nrole = "absorber"\ntemperature_k = -3\n')
    assert main(["thermal", str(path), "--band-um", "8", "12", "--rays", "10", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert "temperature_k" in err and "[[part]] 2" in err


def test_temperature_settings_and_sweep(two_disks, tmp_path):
    """--temperature-k overrides the scene; a sweep is linear in each part's band radiance (the power
    from a part scales with B_band(T)), and its value at the scene temperature is the total itself."""
    out = tmp_path / "sw"
    assert main(["thermal", str(two_disks), "--band-um", "8", "12", "--rays", "4000", "--temperature-k", "b*=290",
                 "--sweep-temperature-k", "baffle", "290", "250", "0", "--out", str(out)]) == 0
    det = json.loads((out / "thermal.json").read_text())["detectors"]["focal_plane"]
    rows = json.loads((out / "thermal_sweep.json").read_text())["rows"]
    assert [r["temperature_k"] for r in rows] == [290.0, 250.0, 0.0]
    base, wall = det["power_w"], det["by_part"]["baffle"]["power_w"]
    assert wall > 0 and rows[0]["power_w"] == pytest.approx(base, rel=1e-12)
    ratio = band_radiance_w_m2_sr(8, 12, 250.0) / band_radiance_w_m2_sr(8, 12, 290.0)
    assert rows[1]["power_w"] == pytest.approx(base - wall + wall * ratio, rel=1e-9)
    assert rows[2]["power_w"] == pytest.approx(base - wall, rel=1e-9, abs=1e-15)
    assert (out / "thermal_sweep.csv").read_text().startswith("detector,part,temperature_k,power_w,stderr_w")


def test_unknown_part_in_temperature_setting(two_disks, tmp_path, capsys):
    assert main(["thermal", str(two_disks), "--band-um", "8", "12", "--rays", "10", "--temperature-k", "tube=300",
                 "--out", str(tmp_path / "x")]) == 2
    assert "no part named 'tube'" in capsys.readouterr().err


def test_rays_are_exact_across_sub_bands(tmp_path):
    """A wavelength-dependent material splits the band into sub-bands; --rays N still traces N."""
    text = part("focal_plane", role="detector", surface=plane((0, 0, 0), (0, 0, 1), 5.0))
    text += part("baffle", "glossy", 300.0, surface=plane((0, 0, 30), (0, 0, -1), 20.0))
    out = tmp_path / "o"
    assert main(["thermal", str(write_scene(tmp_path, text)), "--band-um", "8", "12", "--rays", "1001",
                 "--out", str(out)]) == 0
    assert json.loads((out / "thermal.json").read_text())["rays"] == 1001
    assert len(json.loads((out / "thermal_details.json").read_text())["sub_bands_um"]) == 5
