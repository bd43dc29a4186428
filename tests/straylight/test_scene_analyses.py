"""Every analysis on a scene file (CONTRACTS §4.5) gives the built-in tube's numbers.

The built-in tube is written out with the project's own writer (``write_setup_scene`` ->
``geometry.io.save_scene`` + an ``[analysis]`` table), loaded back as SCENE.toml, and each command
runs on both with the same seed: the numbers must be the same (the same triangles, beam, entrance
and detector trace the same random streams), so any difference is a bug in the scene path.
"""
import json
import math

import numpy as np
import pytest

from straylight.cli.main import main

RAYS = "3000"


@pytest.fixture(scope="module")
def tube_scene(tmp_path_factory):
    from straylight.analyses.builtin import tube_setup
    from straylight.analyses.scene_setup import write_setup_scene

    return write_setup_scene(tube_setup(), tmp_path_factory.mktemp("tube_scene"))


def _both(tmp_path, tube_scene, argv):
    docs = []
    for tag, where in (("builtin", ["--builtin", "tube"]), ("scene", [str(tube_scene)])):
        out = tmp_path / tag
        assert main([argv[0], *where, *argv[1:], "--out", str(out)]) == 0
        docs.append(out)
    return docs


def test_pst_on_scene_file_equals_builtin(tmp_path, tube_scene):
    a, b = _both(tmp_path, tube_scene, ["pst", "--angles-deg", "0", "20", "--rays", RAYS, "--seed", "4"])
    ja, jb = (json.loads((d / "pst.json").read_text()) for d in (a, b))
    assert ja["detector"] == jb["detector"] == "detector"
    assert ja["detector_area_mm2"] == jb["detector_area_mm2"]
    for pa, pb in zip(ja["points"], jb["points"], strict=True):
        for key in ("pst", "pst_stderr", "entrance_ratio", "detector_w", "detector_stderr_w", "rays"):
            assert pa[key] == pytest.approx(pb[key], rel=1e-12), key
    assert ja["points"][1]["pst"] > 0


def test_paths_on_scene_file_equals_builtin(tmp_path, tube_scene):
    a, b = _both(tmp_path, tube_scene, ["paths", "--angle-deg", "20", "--rays", RAYS, "--seed", "2"])
    ja, jb = (json.loads((d / "paths.json").read_text()) for d in (a, b))
    assert ja["total_w"] == pytest.approx(jb["total_w"], rel=1e-12) and ja["total_w"] > 0
    assert [g["label"] for g in ja["groups"]] == [g["label"] for g in jb["groups"]]
    assert [g["fraction"] for g in ja["groups"]] == pytest.approx([g["fraction"] for g in jb["groups"]], rel=1e-12)


def test_critical_on_scene_file_equals_builtin(tmp_path, tube_scene):
    a, b = _both(tmp_path, tube_scene, ["critical", "--angle-deg", "20", "--rays", RAYS, "--seed", "5"])
    ja, jb = (json.loads((d / "critical.json").read_text()) for d in (a, b))
    assert [p["part"] for p in ja["parts"]] == [p["part"] for p in jb["parts"]]
    for pa, pb in zip(ja["parts"], jb["parts"]):
        for key in ("illuminated", "illuminated_stderr", "view_factor", "view_factor_stderr", "score", "score_stderr"):
            assert pa[key] == pytest.approx(pb[key], rel=1e-12, abs=0), key
    assert any(p["score"] > 0 for p in ja["parts"])


def test_view_on_scene_file_writes_png_with_the_same_rays(tmp_path, tube_scene):
    from straylight import viz
    from straylight.analyses.builtin import tube_setup
    from straylight.analyses.scene_setup import scene_setup

    png = tmp_path / "view.png"
    assert main(["view", str(tube_scene), "--angle-deg", "20", "--rays", "30", "--png", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    a = viz.trace_ray_paths(tube_setup(), math.radians(20), n_rays=30, seed=0)
    b = viz.trace_ray_paths(scene_setup(tube_scene), math.radians(20), n_rays=30, seed=0)
    assert len(a) == len(b) == 30
    for wa, wb in zip(a, b):
        np.testing.assert_array_equal(np.asarray(wa[0]), np.asarray(wb[0]))


def test_study_on_scene_file_equals_builtin(tmp_path, tube_scene):
    argv = ["study", "--rays", "1000", "--seed", "1", "--angles-deg", "0", "20", "--no-sweep"]
    a, b = _both(tmp_path, tube_scene, argv)
    ja, jb = (json.loads((d / "results.json").read_text()) for d in (a, b))
    for d in (a, b):
        assert "<img" in (d / "index.html").read_text()
    assert [p["pst"] for p in ja["pst"]["points"]] == pytest.approx([p["pst"] for p in jb["pst"]["points"]],
                                                                     rel=1e-12)
    assert ja["paths"]["total_w"] == pytest.approx(jb["paths"]["total_w"], rel=1e-12)
    assert [p["view_factor"] for p in ja["critical"]["parts"]] == \
        pytest.approx([p["view_factor"] for p in jb["critical"]["parts"]], rel=1e-12)
    assert str(tube_scene) in (b / "index.html").read_text()
    # the scene's report speaks of its own parts and materials, and of the files it wrote
    for name in ("report.md", "index.html"):
        text = (b / name).read_text()
        assert "wall, vanes and end plate" not in text and "sweep.csv" not in text, name
        code = "`" if name == "report.md" else "<code>"  # index.html renders Markdown's backticks as code
        assert f"Material {code}" in text and f"Detector {code}detector" in text and "(mesh of" in text, name
    assert jb["instrument"]["detector"] == "detector" and len(jb["instrument"]["parts"]) == len(ja["instrument"]["parts"])
    assert "sweep.csv" not in (a / "report.md").read_text()  # --no-sweep: none written, none named


# ------------------------------------------------------------------ bad scene files: one line each

def _scene_with(tmp_path, tube_scene, edit):
    import tomllib

    import tomli_w

    doc = tomllib.loads(tube_scene.read_text())
    for part in doc["part"]:
        part["mesh"] = str(tube_scene.parent / part["mesh"])
    edit(doc)
    path = tmp_path / "edited.toml"
    path.write_text(tomli_w.dumps(doc))
    return path


def _no_collimated(doc):
    doc["source"] = [{"type": "point", "position_mm": [0.0, 0.0, 400.0]}]


def _two_detectors(doc):
    doc["part"].append(dict(doc["part"][-1], name="detector_2"))
    doc.pop("analysis")


def _bad_entrance(doc):
    doc["analysis"]["entrance"] = {"center_mm": [0, 0, 300], "radius_mm": 50}


def _unknown_key(doc):
    doc["analysis"]["detectr"] = "detector"


def _not_a_detector(doc):
    doc["analysis"]["detector"] = "wall"


@pytest.mark.parametrize("edit, message", [
    (_no_collimated, "no collimated_disk [[source]]"),
    (_two_detectors, "2 detector parts (detector, detector_2); name one with [analysis] detector"),
    (_bad_entrance, "entrance needs exactly center_mm, normal, radius_mm; missing normal"),
    (_unknown_key, "unknown key(s) detectr"),
    (_not_a_detector, "'wall' is not a detector part"),
])
def test_bad_scene_is_one_line(tmp_path, tube_scene, capsys, edit, message):
    path = _scene_with(tmp_path, tube_scene, edit)
    assert main(["pst", str(path), "--angles-deg", "20", "--rays", "100", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1 and str(path) in err


def _no_such_detector(doc):
    doc["analysis"]["detector"] = "sensr"


@pytest.mark.parametrize("command", [["trace", "--rays", "100", "--json", "{out}/t.json"],
                                     ["pst", "--angles-deg", "20", "--rays", "100", "--out", "{out}"]])
def test_analysis_detector_that_is_no_part_is_refused_by_every_command(tmp_path, tube_scene, capsys, command):
    """A misspelt [analysis] detector is a scene error: `trace`, which does not tilt a beam, refuses it too."""
    path = _scene_with(tmp_path, tube_scene, _no_such_detector)
    out = tmp_path / "o"
    out.mkdir()
    args = [command[0], str(path)] + [a.format(out=out) for a in command[1:]]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert "[analysis] detector 'sensr' is not a detector part" in err and "detectors: detector" in err
    assert len(err.splitlines()) == 1 and str(path) in err
    assert not list(out.iterdir())


def test_default_entrance_is_the_source_disk(tmp_path, tube_scene):
    """Without [analysis] entrance, the disk stays put (BENCHMARK.md) and entrance_ratio = P_det / P."""
    from straylight.analyses.scene_setup import scene_setup

    path = _scene_with(tmp_path, tube_scene, lambda doc: doc["analysis"].pop("entrance"))
    setup = scene_setup(path)
    assert setup.beam.pivot_mm is None
    np.testing.assert_allclose(setup.beam.source(math.radians(20)).center_mm, [0, 0, 310])
    assert setup.entrance.power_w(setup.beam, math.radians(20)) == pytest.approx(1.0)


def test_geometry_build_tube_scene_runs_pst_like_the_builtin(tmp_path):
    """`straylight geometry build tube` writes a scene that every analysis can run (source,
    [analysis] and, for the default name, the BENCHMARK.md coating inline); with the built-in's
    coating and float64 meshes it gives the built-in tube's numbers for the same seed."""
    built = tmp_path / "tube_dir"
    assert main(["geometry", "build", "tube", "--material", "z302_sample_b", "--mesh-format", "ply",
                 "--no-step", "-o", str(built)]) == 0
    a, b = _both(tmp_path, built / "scene.toml", ["pst", "--angles-deg", "20", "--rays", RAYS, "--seed", "4"])
    ja, jb = (json.loads((d / "pst.json").read_text()) for d in (a, b))
    assert ja["points"][0]["pst"] > 0
    assert ja["points"][0]["pst"] == pytest.approx(jb["points"][0]["pst"], rel=1e-12)


def test_geometry_build_tube_default_coating_is_written_inline(tmp_path):
    """The default material name `benchmark_black` is not a preset: the scene file must define it
    (Lambertian rho = 0.05, BENCHMARK.md) or `trace` cannot resolve it."""
    from straylight.scene import load_scene

    built = tmp_path / "tube_dir"
    assert main(["geometry", "build", "tube", "--vanes", "2", "--no-step", "-o", str(built)]) == 0
    rs = load_scene(built / "scene.toml")
    model = rs.materials["benchmark_black"]
    wi = np.array([[0.0, 0.0, 1.0]])
    assert model.brdf(wi, wi)[0] == pytest.approx(0.05 / math.pi)
    res = rs.trace(2000, seed=1)
    assert res.emitted_w > 0
