"""``straylight rig twin`` (rig/cli/twin.py), driven through its own argparse subparsers
(the coordinator wires ``add_parser`` into the ``rig`` group)."""
import argparse
import json

import pytest

from rig.cli import twin as rig_twin


def run(argv):
    parser = argparse.ArgumentParser(prog="straylight rig")
    rig_twin.add_parser(parser.add_subparsers())
    args = parser.parse_args(argv)
    return args.func(args)


def test_twin_command_writes_json_and_plot(tmp_path, capsys):
    out, png = tmp_path / "twin.json", tmp_path / "twin.png"
    code = run(["twin", "--sample", "z302_sample_a", "--theta-i-deg", "30", "--theta-r-deg", "30.5", "40",
                "--polarization", "s", "p", "--rays", "3000", "--seed", "2", "--json", str(out), "--plot", str(png)])
    assert code == 0
    data = json.loads(out.read_text())
    assert data["seed"] == 2 and data["n_rays_per_point"] == 3000 and data["rig"]["arm_mm"] == 200.0
    pts = data["points"]
    assert [(p["theta_r_deg"], p["polarization"]) for p in pts] == [(30.5, "s"), (40.0, "s"), (30.5, "p"), (40.0, "p")]
    for p in pts:
        assert p["twin_brdf_per_sr"] > 0 and p["twin_stderr_per_sr"] > 0 and p["model_brdf_per_sr"] > 0
        assert p["z_model_minus_twin"] == pytest.approx(
            (p["model_brdf_per_sr"] - p["twin_brdf_per_sr"]) / p["twin_stderr_per_sr"])
    assert png.stat().st_size > 10_000 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    printed = capsys.readouterr().out
    assert "twin" in printed and "40.000" in printed


def test_twin_command_mirror_sample(tmp_path):
    out = tmp_path / "m.json"
    assert run(["twin", "--sample", "mirror:0.5", "--theta-i-deg", "20", "--theta-r-deg", "20", "--rays", "2000",
                "--json", str(out), "--slit-width-mm", "0.4"]) == 0
    pt = json.loads(out.read_text())["points"][0]
    assert pt["model_brdf_per_sr"] is None and pt["twin_brdf_per_sr"] > 0 and pt["estimator"] == "walk"


@pytest.mark.parametrize("argv, match", [
    (["--sample", "no_such_preset"], "no_such_preset"),
    (["--sample", "mirror:x"], "mirror"),
    (["--sample", "z302_sample_a", "--rays", "0"], "--rays"),
    (["--sample", "z302_sample_a", "--slit-width-mm", "-1"], "slit_width_mm"),
])
def test_twin_command_bad_input_is_a_value_error(tmp_path, argv, match):
    base = ["twin", "--theta-i-deg", "30", "--theta-r-deg", "31", "--json", str(tmp_path / "x.json")]
    with pytest.raises(ValueError, match=match):
        run(base + argv)


def test_theta_out_of_range_names_the_option(tmp_path):
    with pytest.raises(ValueError, match="--theta-r-deg"):
        run(["twin", "--sample", "z302_sample_a", "--theta-i-deg", "30", "--theta-r-deg", "95",
             "--json", str(tmp_path / "x.json")])
