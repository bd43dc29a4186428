"""``straylight design vanes`` (CONTRACTS 4.6): files, PST against ``straylight pst``, baseline, errors.

One small design run (few rays, a short optimiser budget) is shared by the tests of this module.
Monte Carlo comparisons use 4 sigma of the runs' own standard errors, fixed seeds.
"""
import json
import math
import tomllib

import numpy as np
import pytest

from straylight.cli.main import main
from straylight.design.construction import BaffleSpec, evenly_spaced
from straylight.design.refine import feasible

ARGS = ["--tube-radius-mm", "50", "--tube-length-mm", "300", "--stop-radius-mm", "35", "--field-deg", "0.5",
        "--exclusion-deg", "20"]
E = 20.0


@pytest.fixture(scope="module")
def design_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("design")
    code = main(["design", "vanes", *ARGS, "--vane-thickness-mm", "1", "--rays", "20000", "--refine-rays", "4000",
                 "--refine-evals", "6", "--seed", "3", "--threads", "2", "--out", str(out)])
    assert code == 0
    return out


def test_design_json_contract(design_dir):
    doc = json.loads((design_dir / "design.json").read_text())
    z = [v["z_mm"] for v in doc["vanes"]]
    assert z == sorted(z) and len(z) >= 3
    for v in doc["vanes"] + doc["baseline"]["vanes"]:
        assert set(v) == {"z_mm", "inner_radius_mm", "thickness_mm"} and v["thickness_mm"] == 1.0
        # inner edge on the field envelope S + (z + t/2) tan F (square edge: the top corner binds)
        assert v["inner_radius_mm"] == pytest.approx(35 + (v["z_mm"] + 0.5) * math.tan(math.radians(0.5)))
    angles = [p["off_axis_deg"] for p in doc["pst"]]
    assert E in angles and E + 10 in angles
    assert [p["off_axis_deg"] for p in doc["baseline"]["pst"]] == angles
    assert all(p["pst"] > 0 and p["pst_stderr"] > 0 for p in doc["pst"] + doc["baseline"]["pst"])
    # baseline: same count, evenly spaced z_k = k L / (N + 1)
    n = len(doc["vanes"])
    assert [v["z_mm"] for v in doc["baseline"]["vanes"]] == pytest.approx([300 * k / (n + 1) for k in range(1, n + 1)])
    assert doc["baseline"]["pst"][0]["rays"] == doc["pst"][0]["rays"] == 20000
    assert doc["geometry"]["vignetting_margin_mm"] >= -1e-9
    if doc["design_source"] == "construction":
        assert doc["geometry"]["complete"] and doc["geometry"]["lit_and_seen_mm"] == 0
    # the bare tube is far brighter than either vane layout (sanity of the comparison)
    assert doc["no_vanes"]["pst"][0]["pst"] > 20 * doc["pst"][0]["pst"]
    for name in ("scene.toml", "design.step", "index.html", "layout.png", "pst.png"):
        assert (design_dir / name).stat().st_size > 0
    assert (design_dir / "design.step").read_text(errors="ignore").startswith("ISO-10303-21")
    html = (design_dir / "index.html").read_text()
    assert "layout.png" in html and "pst.png" in html


def test_scene_file_parts_and_source(design_dir):
    doc = tomllib.loads((design_dir / "scene.toml").read_text())
    names = [p["name"] for p in doc["part"]]
    n = len(json.loads((design_dir / "design.json").read_text())["vanes"])
    assert names == ["wall"] + [f"vane_{k}" for k in range(1, n + 1)] + ["end_plate", "detector"]
    assert [p["role"] for p in doc["part"]][-1] == "detector"
    (src,) = doc["source"]
    assert src["type"] == "collimated_disk" and src["direction"] == [0.0, 0.0, -1.0]


def test_pst_agrees_with_straylight_pst_on_the_written_scene(design_dir, tmp_path):
    """Same definition: with the same seed the numbers are identical; with another seed they agree
    within 4 sigma of the two runs' errors."""
    doc = json.loads((design_dir / "design.json").read_text())
    angles = [str(p["off_axis_deg"]) for p in doc["pst"]]
    for seed, out in ((3, tmp_path / "same"), (11, tmp_path / "other")):
        assert main(["pst", str(design_dir / "scene.toml"), "--angles-deg", *angles, "--rays", "20000",
                     "--seed", str(seed), "--out", str(out)]) == 0
    same = json.loads((tmp_path / "same" / "pst.json").read_text())["points"]
    other = json.loads((tmp_path / "other" / "pst.json").read_text())["points"]
    for ours, s, o in zip(doc["pst"], same, other):
        assert s["pst"] == pytest.approx(ours["pst"], rel=1e-9)
        assert abs(o["pst"] - ours["pst"]) <= 4 * math.hypot(o["pst_stderr"], ours["pst_stderr"])
        assert o["pst"] != ours["pst"]  # really another sample


def test_design_not_worse_than_baseline_at_e_and_e_plus_10(design_dir):
    doc = json.loads((design_dir / "design.json").read_text())
    for d, b in zip(doc["pst"], doc["baseline"]["pst"]):
        if d["off_axis_deg"] in (E, E + 10):
            assert d["pst"] <= b["pst"] + 4 * math.hypot(d["pst_stderr"], b["pst_stderr"]), d["off_axis_deg"]


def test_optimiser_history(design_dir):
    opt = json.loads((design_dir / "design.json").read_text())["optimiser"]
    traced = [e for e in opt["evaluations"] if e["objective"] is not None]
    assert 2 <= len(traced) <= 6 and opt["stop_reason"]
    assert opt["best_objective"] == pytest.approx(min(e["objective"] for e in traced))
    assert opt["angles_deg"] == [E, E + 5, E + 10]


@pytest.mark.parametrize("extra, message", [
    (["--stop-radius-mm", "50"], "stop_radius_mm (50) must be below tube_radius_mm (50)"),
    (["--field-deg", "25"], "field_deg (25) must be below exclusion_deg (20)"),
    (["--field-deg", "3"], "too wide for the tube"),
    (["--tube-length-mm", "-5"], "tube_length_mm must be a finite number > 0"),
    (["--rays", "0"], "--rays must be >= 1"),
    (["--keep-out-mm", "10", "400"], "keep-out zone (10, 400)"),
])
def test_bad_inputs_give_one_line_errors(extra, message, capsys, tmp_path):
    assert main(["design", "vanes", *ARGS, *extra, "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err and err.startswith("straylight: error:")


def test_feasible_rejects_overlap_outside_and_keep_out():
    spec = BaffleSpec(50, 300, 35, 0, 20, keep_out_mm=((100, 120),))
    assert feasible(spec, [50, 150, 250]) is None
    assert feasible(spec, [50, 50.5, 250]) == "vanes overlap"
    assert feasible(spec, [0.2, 150]) == "outside the tube"
    assert feasible(spec, [50, 110, 250]) == "in a keep-out zone"
    assert np.allclose([v.z_mm for v in evenly_spaced(spec, 3).vanes], [75, 150, 225])


def test_refine_stops_on_the_error_rule_and_finds_the_minimum(monkeypatch):
    """With a smooth stand-in for the traced PST (ln PST = ((z - z*) / 20 mm)^2 summed, 1 % errors),
    Nelder-Mead reaches z* and stops because the simplex values lie within se(J), not on the budget."""
    import straylight.design.refine as refine_mod
    from straylight.design.evaluate import PstPoint

    target = np.array([60.0, 130.0, 240.0])

    def fake(spec, vanes, models, angles, rays, seed, execution=None):
        z = np.array([v.z_mm for v in vanes])
        lnp = float(np.sum(((z - target) / 20.0) ** 2)) - 12.0
        return [PstPoint(a, math.exp(lnp), 0.01 * math.exp(lnp), rays) for a in angles]

    monkeypatch.setattr(refine_mod, "pst_points", fake)
    spec = BaffleSpec(50, 300, 35, 0, 20)
    res = refine_mod.refine(spec, [50.0, 140.0, 230.0], {}, [20, 25, 30], rays=10, seed=0, max_evals=200,
                            also_z_mm=[75.0, 150.0, 225.0])
    assert res.stop_reason.startswith("converged")
    assert res.fatol == pytest.approx(0.01 / math.sqrt(3))
    assert np.allclose(res.best_z_mm, target, atol=20 * math.sqrt(res.fatol) + 0.5)
    assert res.best_objective < res.start_objective


def test_material_file_goes_inline_into_the_scene(tmp_path):
    """--material FILE: the scene file carries the material as [material.coating], so it is self-contained."""
    from straylight.design import construct_vanes, model
    from straylight.scene import load_scene

    mat = tmp_path / "my_black.json"
    mat.write_text(json.dumps({"name": "my_black", "components": [{"type": "lambertian", "rd": 0.05}]}))
    layout = construct_vanes(50, 300, 35, 0, 30)
    path = model.write_scene(layout.spec, layout.vanes, str(mat), tmp_path / "scene")
    mat.unlink()
    rs = load_scene(path)
    assert rs.materials["coating"].name == "my_black"
    (src,) = rs.sources
    # the fixed beam disk covers the entrance and rim up to 85 deg: radius >= 51 + 0.2 tan 85
    assert src.radius_mm >= 51 + 0.2 * math.tan(math.radians(85)) - 1e-9


@pytest.mark.slow
def test_default_design_of_the_reference_tube(tmp_path):
    """The README's example at the command's defaults (100 000 rays, 40 layouts; ~2 min on 2 cores):
    the design is not brighter than the evenly spaced baseline beyond 4 sigma at E and E + 10."""
    args = [a if a != "0.5" else "0" for a in ARGS]  # F = 0: the built-in tube's 35 mm holes
    assert main(["design", "vanes", *args, "--out", str(tmp_path)]) == 0
    doc = json.loads((tmp_path / "design.json").read_text())
    assert len(doc["vanes"]) == 5 and doc["construction"]["geometry"]["complete"]
    for d, b in zip(doc["pst"], doc["baseline"]["pst"]):
        if d["off_axis_deg"] in (E, E + 10):
            assert d["pst"] <= b["pst"] + 4 * math.hypot(d["pst_stderr"], b["pst_stderr"])


def test_choose_design_never_returns_a_layout_worse_than_the_baseline_at_some_angle():
    from straylight.design.evaluate import PstPoint
    from straylight.design.vanes import choose_design

    def pts(*pst):
        return [PstPoint(a, p, 0.01 * p, 1000) for a, p in zip((20.0, 25.0, 30.0), pst)]

    base = ("base", pts(1.0, 1.0, 1.0), "evenly spaced")
    trades = ("trades", pts(0.5, 0.5, 1.3), "refined")  # better band objective, 30 % worse at E + 10
    better = ("better", pts(0.9, 0.9, 1.0), "construction")
    assert choose_design([trades], base)[2] == "evenly spaced"
    assert choose_design([trades, better], base)[2] == "construction"
    assert choose_design([("noise", pts(0.5, 0.5, 1.01), "refined")], base)[2] == "refined"  # within 2 sigma
