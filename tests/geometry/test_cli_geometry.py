"""`straylight geometry build tube|reflectometer` and `geometry check`."""
import json

from geometry.io import load_scene
from straylight.cli.main import main


def test_build_tube_writes_step_stl_and_scene(tmp_path, capsys):
    out = tmp_path / "tube"
    rc = main(["geometry", "build", "tube", "--vanes", "3", "--tolerance-mm", "0.1", "-o", str(out),
               "--json", str(tmp_path / "r.json")])
    assert rc == 0
    text = capsys.readouterr().out
    assert "max_chord_error_mm" in text and "checks: ok" in text
    names = ["wall", "vane_1", "vane_2", "vane_3", "end_plate", "detector"]
    for name in names:
        assert (out / f"{name}.step").is_file() and (out / f"{name}.stl").is_file()
    scene = load_scene(out / "scene.toml")
    assert list(scene.part_names) == names
    report = json.loads((tmp_path / "r.json").read_text())
    assert all(r["max_chord_error_mm"] <= 0.1 for r in report["tessellation"])
    assert sum(r["n_triangles"] for r in report["tessellation"]) == len(scene.triangles_mm)
    assert main(["geometry", "check", str(out / "scene.toml")]) == 0


def test_bad_parameter_is_a_one_line_error(tmp_path, capsys):
    rc = main(["geometry", "build", "tube", "--vane-bevel-deg", "95", "-o", str(tmp_path)])
    err = capsys.readouterr().err
    assert rc == 2 and "vane_bevel_deg" in err and err.count("\n") == 1


def test_build_reflectometer(tmp_path):
    rc = main(["geometry", "build", "reflectometer", "--theta-i-deg", "10", "--theta-r-deg", "10",
               "--sample-material", "z302", "--no-step", "-o", str(tmp_path)])
    assert rc == 0
    scene = load_scene(tmp_path / "scene.toml")
    assert scene.part("sample").material == "z302" and scene.part("detector").role == "detector"
