"""``straylight study`` adds the self-emission budget when parts have temperature_k."""
import json
import warnings

import pytest

from straylight.cli.main import main
from tests.validation.thermal_scenes import part, plane, write_scene, write_tube_inward

SOURCE = """
[[source]]
type = "collimated_disk"
center_mm = [0.0, 0.0, 60.0]
normal = [0.0, 0.0, -1.0]
direction = [0.0, 0.0, -1.0]
radius_mm = 12.0
"""


def _scene(tmp_path):
    wall = write_tube_inward(tmp_path, 10.0, 50.0, n_phi=48, n_z=2)
    text = part("wall", "black", 300.0, mesh=wall)
    text += part("focal_plane", role="detector", temperature_k=77.0, surface=plane((0, 0, 0), (0, 0, 1), 6.0))
    return write_scene(tmp_path, text + SOURCE)


def test_thermal_step_and_report_section(tmp_path):
    """The study's thermal step alone (fast): files, budget, narcissus line."""
    from straylight.analyses.scene_setup import scene_setup
    from straylight.thermal.report import report_section, thermal_step

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        setup = scene_setup(_scene(tmp_path))
    res = thermal_step(setup, tmp_path, (8.0, 12.0), seed=2)
    det = res.detectors["focal_plane"]
    assert det.stderr_w <= 0.01 * det.power_w and set(det.by_part) == {"wall", "focal_plane"}
    assert (tmp_path / "thermal_budget.png").stat().st_size > 5_000
    page = report_section(tmp_path)
    assert "Self-emission budget, 8-12 um" in page and "Narcissus" in page and "wall" in page
    assert report_section(tmp_path / "nothing") == ""


@pytest.mark.slow
def test_study_reports_self_emission_and_narcissus(tmp_path):
    path = _scene(tmp_path)
    out = tmp_path / "study"
    assert main(["study", str(path), "--rays", "300", "--angles-deg", "0", "--path-angle-deg", "0",
                 "--no-sweep", "--band-um", "3", "5", "--out", str(out)]) == 0
    page = (out / "index.html").read_text()
    assert "Self-emission budget, 3-5 um" in page and 'src="thermal_budget.png"' in page and "Narcissus" in page
    assert (out / "thermal_budget.png").stat().st_size > 5_000
    doc = json.loads((out / "results.json").read_text())["thermal"]
    det = doc["detectors"]["focal_plane"]
    assert doc["band_um"] == [3.0, 5.0] and set(det["by_part"]) == {"wall", "focal_plane"}
    assert det["stderr_w"] <= 0.01 * det["power_w"] and det["by_part"]["wall"]["power_w"] > 0
