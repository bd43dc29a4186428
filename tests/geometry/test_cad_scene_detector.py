"""Instruments without a detector solid (CONTRACTS §6.4): ``straylight geometry scene --detector-disk``
adds an exact analytic detector disk; without a detector the scene is written and every analysis
refuses it in one line naming what to add."""
import json
import math
from pathlib import Path

import pytest

from straylight.cli.main import main

DATA = Path(__file__).parents[1] / "data" / "cad"


@pytest.fixture(autouse=True)
def _cached_tessellation(tmp_path, monkeypatch):
    """Each command below reads the same STEP file: tessellate it once (the cache, in this test's folder)."""
    monkeypatch.setenv("STRAYLIGHT_CACHE", "on")
    monkeypatch.setenv("STRAYLIGHT_CACHE_DIR", str(tmp_path / "cache"))


def test_scene_without_a_detector_is_written_and_the_analyses_refuse_it_in_one_line(tmp_path, capsys):
    toml = tmp_path / "g.toml"
    assert main(["geometry", "scene", str(DATA / "gmsh_parts.step"), "-o", str(toml)]) == 0
    out = capsys.readouterr().out
    assert "no detector yet" in out and "--detector-disk" in out
    assert "NO DETECTOR YET" in toml.read_text()
    for command in (["pst", str(toml), "--angles-deg", "5", "--rays", "200", "--out", str(tmp_path / "p")],
                    ["paths", str(toml), "--angle-deg", "5", "--rays", "200", "--out", str(tmp_path / "q")],
                    ["study", str(toml), "--rays", "200", "--out", str(tmp_path / "s")]):
        assert main(command) != 0, command[0]
        errors = [line for line in capsys.readouterr().err.splitlines() if "error" in line]
        assert len(errors) == 1, errors  # (study prints its steps before it)
        err = errors[0]
        assert "no detector part" in err and "role = \"detector\"" in err and "--detector-disk" in err, err
        assert str(toml) in err


def test_detector_disk_from_the_command_line_is_an_exact_detector(tmp_path, capsys):
    """The disk sits on the assembly's axis below its top, facing up (+z: where the beam comes from);
    the PST divides by its exact area pi R^2, and light reaches it."""
    toml = tmp_path / "b.toml"
    with pytest.raises(SystemExit):  # argparse: one or the other
        main(["geometry", "scene", str(DATA / "ocp_bench_m.step"), "-o", str(toml), "--tolerance-mm", "0.1",
              "--detector", "detector", "--detector-disk", "0", "0", "1", "0", "0", "1", "2"])
    capsys.readouterr()
    assert main(["geometry", "scene", str(DATA / "ocp_bench_m.step"), "-o", str(toml), "--tolerance-mm", "0.1",
                 "--detector-disk", "0", "0", "1", "0", "0", "1", "2.5",
                 "--entrance-disk", "0", "0", "60", "0", "0", "1", "10"]) == 0
    out = capsys.readouterr().out
    assert "exact disk r = 2.5 mm" in out and "no detector yet" not in out
    from straylight.scene import load_scene

    rs = load_scene(toml)
    det = rs.scene.part("detector")
    assert det.role == "detector" and det.surface.area_mm2 == pytest.approx(math.pi * 2.5 ** 2, rel=1e-15)
    assert rs.scene.part("ocp_bench_m/detector").role == "surface"  # the solid is not the detector now
    assert main(["pst", str(toml), "--angles-deg", "0", "--rays", "3000", "--seed", "1", "--out",
                 str(tmp_path / "p")]) == 0
    pst = json.loads((tmp_path / "p" / "pst.json").read_text())
    assert pst["detector"] == "detector"
    assert pst["detector_area_mm2"] == pytest.approx(math.pi * 2.5 ** 2, rel=1e-15)


@pytest.mark.parametrize("disk, words", [(["0", "0", "1", "0", "0", "0", "2"], "normal"),
                                         (["0", "0", "1", "0", "0", "1", "-2"], "radius")])
def test_bad_detector_disk_is_a_one_line_error(tmp_path, capsys, monkeypatch, disk, words):
    """Refused before the assembly is read and meshed (a progress line of a slow meshing would be a
    second line, and the user would wait for nothing)."""
    import geometry.io

    def no_meshing(*args, **kwargs):
        raise AssertionError("the assembly was meshed before the bad disk was refused")

    monkeypatch.setattr(geometry.io, "load_cad_parts", no_meshing)
    assert main(["geometry", "scene", str(DATA / "gmsh_parts.step"), "-o", str(tmp_path / "x.toml"),
                 "--detector-disk", *disk]) != 0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and words in err and "--detector-disk" in err
