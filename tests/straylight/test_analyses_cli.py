"""The thin CLI layers: pst, paths and view write their files; bad input is one line and exit 2."""
import json

import pytest

from straylight.cli.main import main


def test_pst_cli_writes_csv_json_png(tmp_path, capsys):
    out = tmp_path / "pst"
    rc = main(["pst", "--builtin", "tube", "--vanes", "0", "--material", "z302_sample_a", "--angles-deg", "0", "20",
               "--rays", "2000", "--seed", "3", "--out", str(out)])
    assert rc == 0
    doc = json.loads((out / "pst.json").read_text())
    assert [p["off_axis_deg"] for p in doc["points"]] == [0.0, 20.0]
    assert doc["points"][0]["pst"] > doc["points"][1]["pst"] > 0
    for name in ("pst.csv", "pst.png", "entrance_ratio.png"):
        assert (out / name).stat().st_size > 0


def test_paths_cli(tmp_path):
    out = tmp_path / "paths"
    rc = main(["paths", "--builtin", "tube", "--vanes", "0", "--angle-deg", "25", "--rays", "3000",
               "--group-by", "last_part", "--out", str(out)])
    assert rc == 0
    assert "| rank | path |" in (out / "paths.md").read_text()
    assert json.loads((out / "paths.json").read_text())["total_w"] > 0


@pytest.mark.parametrize("argv, message", [
    (["pst", "--out", "x"], "either SCENE.toml or --builtin tube"),
    (["pst", "--builtin", "tube", "--vanes", "0", "--angles-deg", "95", "--out", "x"], "must be in (-90, 90) deg"),
    (["paths", "--builtin", "tube", "--vanes", "0", "--angle-deg", "20", "--detector", "wall", "--out", "x"],
     "not a detector part"),
    (["study", "--out", "x", "--rays", "5"], "--rays must be at least 100"),
])
def test_bad_input_is_one_line_exit_2(argv, message, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1


def test_pst_cli_one_angle_writes_no_curve_unless_asked(tmp_path, capsys):
    """One off-axis angle is one point: no pst.png (a stale one from an earlier sweep into DIR goes), unless --plot."""
    out = tmp_path / "pst"
    out.mkdir()
    (out / "pst.png").write_bytes(b"an earlier sweep's curve")
    argv = ["pst", "--builtin", "tube", "--vanes", "0", "--angles-deg", "20", "--rays", "1000", "--out", str(out)]
    assert main(argv) == 0
    assert not (out / "pst.png").exists() and not (out / "entrance_ratio.png").exists()
    assert "no curve to plot" in capsys.readouterr().out
    assert json.loads((out / "pst.json").read_text())["points"][0]["off_axis_deg"] == 20.0
    assert main(argv + ["--plot"]) == 0
    assert (out / "pst.png").stat().st_size > 0 and (out / "entrance_ratio.png").stat().st_size > 0
