"""CONTRACTS §6 scene files and §4.3 ``straylight trace``, on scenes built here with trimesh/cadquery.

Golden values are geometric and analytic:
- a Lambertian plate (rd) under a collimated beam sends rd of the power back up, all escaping;
- an isotropic point source at height h above a detector square of half-side a puts
  Omega / (4 pi) on it, Omega = 4 arctan(a^2 / (h sqrt(2 a^2 + h^2))) (solid angle of a rectangle);
- a 45 deg mirror (reflectance 1) folds a collimated beam onto a detector: all of it.
"""
import json
import math
from pathlib import Path

import numpy as np
import pytest
import trimesh

from contract_helpers import assert_one_line_error, run_console, write_json

KEYS = ("rays", "seed", "emitted_w", "detectors", "absorbed", "escaped_w", "escaped_stderr_w")


def _box(extents, center=(0, 0, 0), rot_x_deg=0.0):
    m = trimesh.creation.box(extents=extents)
    if rot_x_deg:
        m.apply_transform(trimesh.transformations.rotation_matrix(math.radians(rot_x_deg), [1, 0, 0]))
    m.apply_translation(center)
    return m


def _square(half, z):
    v = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]], float)
    return trimesh.Trimesh(v, [[0, 1, 2], [0, 2, 3]], process=False)


def _toml_value(v):
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return repr(float(v)) if isinstance(v, float) else str(v)


def _scene(path, parts, sources, materials=None):
    lines = []
    for key, comps in (materials or {}).items():
        lines.append(f"[material.{key}]")
        lines.append("components = [" + ", ".join(
            "{" + ", ".join(f"{k} = {_toml_value(v)}" for k, v in c.items()) + "}" for c in comps) + "]")
    for p in parts:
        lines.append("[[part]]")
        lines += [f"{k} = {_toml_value(v)}" for k, v in p.items()]
    for s in sources:
        lines.append("[[source]]")
        lines += [f"{k} = {_toml_value(v)}" for k, v in s.items()]
    path.write_text("\n".join(lines) + "\n")
    return path


BEAM = {"type": "collimated_disk", "center_mm": [0.0, 0.0, 50.0], "normal": [0.0, 0.0, -1.0],
        "direction": [0.0, 0.0, -1.0], "radius_mm": 10.0, "power_w": 1.0}


def _trace(cli, scene, out, rays=4000, seed=3, extra=()):
    rc, _, err = cli("trace", scene, "--rays", rays, "--seed", seed, "--json", out, *extra)
    assert rc == 0, err
    doc = json.loads(Path(out).read_text())
    for key in KEYS:
        assert key in doc, f"trace OUT.json lacks {key!r}"
    assert doc["rays"] == rays and doc["seed"] == seed
    total = (sum(d["power_w"] for d in doc["detectors"].values())
             + sum(a["power_w"] for a in doc["absorbed"].values()) + doc["escaped_w"])
    roulette = 0.0  # CONTRACTS §4.3: roulette must be reported if kept outside 'absorbed'
    if "roulette_w" in doc:
        roulette = doc["roulette_w"]
    assert total + roulette == pytest.approx(doc["emitted_w"], rel=1e-9, abs=1e-12)
    for tally in list(doc["detectors"].values()) + list(doc["absorbed"].values()):
        assert set(tally) >= {"power_w", "stderr_w"} and tally["stderr_w"] >= 0
    return doc


@pytest.mark.parametrize("fmt", ["stl", "obj", "ply", "step"])
def test_lambertian_plate_each_mesh_format(cli, tmp_path, fmt):
    rd = 0.3
    if fmt == "step":
        import cadquery as cq

        cq.exporters.export(cq.Workplane("XY").box(100, 100, 2).translate((0, 0, -1)), str(tmp_path / "plate.step"))
    else:
        _box([100, 100, 2], (0, 0, -1)).export(tmp_path / f"plate.{fmt}")
    scene = _scene(tmp_path / "plate.toml",
                   [{"name": "plate", "mesh": f"plate.{fmt}", "material": "grey", "role": "surface",
                     "tolerance_mm": 0.1}],
                   [BEAM], {"grey": [{"type": "lambertian", "rd": rd}]})
    doc = _trace(cli, scene, tmp_path / "o.json")
    assert doc["emitted_w"] == pytest.approx(1.0)
    assert doc["escaped_w"] > 0
    assert abs(doc["escaped_w"] - rd) <= max(4 * doc["escaped_stderr_w"], 1e-9)
    absorbed = sum(a["power_w"] for a in doc["absorbed"].values())
    assert absorbed == pytest.approx(1 - rd, abs=max(4 * doc["escaped_stderr_w"], 1e-9))


def test_point_source_over_detector_square(cli, tmp_path):
    a, h, power = 20.0, 30.0, 2.5
    _square(a, 0.0).export(tmp_path / "det.obj")
    scene = _scene(tmp_path / "pt.toml", [{"name": "fp", "mesh": "det.obj", "role": "detector"}],
                   [{"type": "point", "position_mm": [0.0, 0.0, h], "power_w": power}])
    doc = _trace(cli, scene, tmp_path / "o.json", rays=20000)
    omega = 4 * math.atan(a * a / (h * math.sqrt(2 * a * a + h * h)))
    det = doc["detectors"]["fp"]
    assert det["power_w"] > 0 and det["stderr_w"] > 0
    assert abs(det["power_w"] - power * omega / (4 * math.pi)) <= 4 * det["stderr_w"]
    assert doc["emitted_w"] == pytest.approx(power)


def test_point_cone_and_lambertian_disk_over_detector_square(cli, tmp_path):
    """A cone of half-angle 60 deg holding the square: Omega / (2 pi (1 - cos 60)). A tiny Lambertian disk
    facing the square: 4 x the differential-to-parallel-rectangle view factor (corner above the corner),
    F = (1 / 2 pi) [A / sqrt(1 + A^2) atan(A / sqrt(1 + A^2)) x 2], A = a / h."""
    a, h = 20.0, 30.0
    _square(a, 0.0).export(tmp_path / "det.stl")
    omega = 4 * math.atan(a * a / (h * math.sqrt(2 * a * a + h * h)))
    A = a / h
    view = 4 * (2 * A / math.sqrt(1 + A * A) * math.atan(A / math.sqrt(1 + A * A))) / (2 * math.pi)
    cases = [({"type": "point", "position_mm": [0.0, 0.0, h], "axis": [0.0, 0.0, -1.0], "half_angle_deg": 60.0},
              omega / (2 * math.pi * (1 - math.cos(math.radians(60))))),
             ({"type": "lambertian_disk", "center_mm": [0.0, 0.0, h], "normal": [0.0, 0.0, -1.0], "radius_mm": 1e-3},
              view)]
    for k, (src, expect) in enumerate(cases):
        scene = _scene(tmp_path / f"c{k}.toml", [{"name": "fp", "mesh": "det.stl", "role": "detector"}], [src])
        det = _trace(cli, scene, tmp_path / f"o{k}.json", rays=20000)["detectors"]["fp"]
        assert det["power_w"] > 0 and det["stderr_w"] > 0
        assert abs(det["power_w"] - expect) <= 4 * det["stderr_w"], (src["type"], det, expect)


def test_mirror_step_folds_beam_onto_detector(cli, tmp_path):
    import cadquery as cq

    mirror = cq.Workplane("XY").box(40, 40, 2).translate((0, 0, -1)).rotate((0, 0, 0), (1, 0, 0), 45)
    cq.exporters.export(mirror, str(tmp_path / "mirror.step"))
    _box([100, 2, 100], (0, -60, 0)).export(tmp_path / "det.ply")
    scene = _scene(tmp_path / "fold.toml",
                   [{"name": "fold", "mesh": "mirror.step", "role": "mirror"},
                    {"name": "screen", "mesh": "det.ply", "role": "detector"}], [dict(BEAM, radius_mm=5.0)])
    doc = _trace(cli, scene, tmp_path / "o.json")
    assert doc["detectors"]["screen"]["power_w"] == pytest.approx(1.0, rel=1e-9)


def test_sources_are_virtual(cli, tmp_path):
    """A flat mirror sends the beam straight back through the source disk to a detector above it."""
    _box([100, 100, 2], (0, 0, -1)).export(tmp_path / "m.stl")
    _square(50.0, 100.0).export(tmp_path / "top.stl")
    scene = _scene(tmp_path / "v.toml", [{"name": "m", "mesh": "m.stl", "role": "mirror"},
                                         {"name": "top", "mesh": "top.stl", "role": "detector"}], [BEAM])
    doc = _trace(cli, scene, tmp_path / "o.json")
    assert doc["detectors"]["top"]["power_w"] == pytest.approx(1.0, rel=1e-9)


def _mixed_scene(tmp_path):
    """Inline, file-path and preset materials; every source type; meshes in a subdirectory."""
    from materials import list_presets

    (tmp_path / "meshes").mkdir()
    (tmp_path / "mats").mkdir()
    _box([60, 60, 2], (0, 0, -1)).export(tmp_path / "meshes" / "floor.stl")
    _box([2, 60, 40], (-31, 0, 20)).export(tmp_path / "meshes" / "wall.stl")
    _box([2, 60, 40], (31, 0, 20)).export(tmp_path / "meshes" / "wall2.stl")
    _box([60, 60, 2], (0, 0, 41)).export(tmp_path / "meshes" / "lid.stl")
    write_json(tmp_path / "mats" / "paint.json", {"name": "paint", "wavelength_nm": 633.0, "components": [
        {"type": "lambertian", "rd": 0.05}, {"type": "abg", "a": 1e-3, "b": 1e-3, "g": 2.0}]})
    parts = [{"name": "floor", "mesh": "meshes/floor.stl", "material": "black", "role": "surface"},
             {"name": "wall", "mesh": "meshes/wall.stl", "material": "mats/paint.json", "role": "surface"},
             {"name": "wall2", "mesh": "meshes/wall2.stl", "material": list_presets()[0], "role": "surface"},
             {"name": "lid", "mesh": "meshes/lid.stl", "role": "detector"}]
    sources = [dict(BEAM, center_mm=[0.0, 0.0, 30.0], direction=[0.3, 0.0, -0.954], radius_mm=5.0),
               {"type": "lambertian_disk", "center_mm": [0.0, 0.0, 0.5], "normal": [0.0, 0.0, 1.0],
                "radius_mm": 5.0, "power_w": 0.5},
               {"type": "point", "position_mm": [0.0, 10.0, 20.0], "power_w": 0.25}]
    return _scene(tmp_path / "mixed.toml", parts, sources,
                  {"black": [{"type": "lambertian", "rd": 0.04},
                             {"type": "k_correlation", "sigma_nm": 5.0, "lc_um": 3.0, "s": 2.5, "n": [1.6, 0.1]}]})


def test_mixed_scene_materials_sources_and_conservation(cli, tmp_path, monkeypatch):
    scene = _mixed_scene(tmp_path)
    elsewhere = tmp_path / "run"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)  # paths are relative to the scene file, not the working directory
    # the k_correlation of the inline material needs a wavelength: none given -> one-line error
    rc, _, err = cli("trace", scene, "--rays", 100, "--json", "o.json")
    assert_one_line_error(rc, err, "wavelength_nm")
    text = scene.read_text().replace("[material.black]", "[material.black]\nwavelength_nm = 633.0")
    scene.write_text(text)
    doc = _trace(cli, Path("..") / "mixed.toml", "o.json", rays=3000, seed=11)
    assert doc["emitted_w"] == pytest.approx(1.75)
    assert doc["detectors"]["lid"]["power_w"] > 0
    assert doc["escaped_w"] > 0  # the box has open ends along y


def test_same_seed_same_numbers_any_workers(cli, tmp_path):
    scene = _mixed_scene(tmp_path)
    scene.write_text(scene.read_text().replace("[material.black]", "[material.black]\nwavelength_nm = 633.0"))
    docs = [_trace(cli, scene, tmp_path / f"o{k}.json", rays=3000, seed=5, extra=extra)
            for k, extra in enumerate([(), ("--workers", 1), ("--workers", 2), ("--batch-rays", 700),
                                       ("--threads", 2)])]
    strip = [{k: d[k] for k in KEYS} for d in docs]
    assert strip[0] == strip[1] == strip[2] == strip[3] == strip[4]
    other = _trace(cli, scene, tmp_path / "o9.json", rays=3000, seed=6)
    assert other["escaped_w"] != docs[0]["escaped_w"]


def test_source_outside_scene_and_open_part_warn_but_trace(cli, tmp_path):
    _box([20, 20, 2]).export(tmp_path / "b.stl")
    _square(10.0, 5.0).export(tmp_path / "open.stl")
    scene = _scene(tmp_path / "s.toml", [{"name": "b", "mesh": "b.stl", "role": "absorber"},
                                         {"name": "open", "mesh": "open.stl", "role": "absorber"}],
                   [dict(BEAM, center_mm=[500.0, 0.0, 50.0])])
    rc, _, err = cli("trace", scene, "--rays", 500, "--json", tmp_path / "o.json")
    assert rc == 0, err
    assert "open" in err and "watertight" in err
    assert "[[source]] 1" in err
    doc = json.loads((tmp_path / "o.json").read_text())
    assert doc["escaped_w"] == pytest.approx(doc["emitted_w"])


BAD_SCENES = [
    ("missing mesh", lambda t: t.replace('"b.stl"', '"nope.stl"'), ["nope.stl"]),
    ("unknown material", lambda t: t.replace('material = "grey"', 'material = "unobtainium"'), ["unobtainium"]),
    ("unknown part key", lambda t: t.replace('role = "surface"', 'role = "surface"\ncolour = "red"'), ["colour"]),
    ("bad role", lambda t: t.replace('role = "surface"', 'role = "lens"'), ["lens"]),
    ("unknown source type", lambda t: t.replace('"collimated_disk"', '"laser"'), ["laser"]),
    ("bad source vector", lambda t: t.replace("normal = [0.0, 0.0, -1.0]", "normal = [0.0, 0.0]"), ["normal"]),
    ("no source", lambda t: t.split("[[source]]")[0], ["source"]),
    ("surface without material", lambda t: t.replace('material = "grey"\n', ""), ["material"]),
    ("bad inline material", lambda t: t.replace("rd = 0.3", "rd = 0.3, rdd = 1"), ["rdd"]),
    ("missing material file", lambda t: t.replace('material = "grey"', 'material = "mats/none.json"'), ["none.json"]),
    ("toml syntax", lambda t: t.replace("[[part]]", "[[part]\n"), ["s.toml"]),
]


@pytest.mark.parametrize("desc,edit,needles", BAD_SCENES, ids=[b[0] for b in BAD_SCENES])
def test_bad_scene_one_line_error(cli, tmp_path, desc, edit, needles):
    _box([20, 20, 2]).export(tmp_path / "b.stl")
    scene = _scene(tmp_path / "s.toml", [{"name": "b", "mesh": "b.stl", "material": "grey", "role": "surface"}],
                   [BEAM], {"grey": [{"type": "lambertian", "rd": 0.3}]})
    scene.write_text(edit(scene.read_text()))
    rc, _, err = cli("trace", scene, "--rays", 100, "--json", tmp_path / "o.json")
    assert_one_line_error(rc, err, "s.toml", *needles)
    assert not (tmp_path / "o.json").exists()


@pytest.mark.parametrize("argv", [["--rays", "0"], ["--rays", "10", "--workers", "0"], ["--rays", "ten"],
                                  ["--rays", "10", "--threads", "0"]])
def test_bad_trace_options(cli, tmp_path, argv):
    _box([20, 20, 2]).export(tmp_path / "b.stl")
    scene = _scene(tmp_path / "s.toml", [{"name": "b", "mesh": "b.stl", "role": "absorber"}], [BEAM])
    rc, _, err = cli("trace", scene, "--json", tmp_path / "o.json", *argv)
    assert rc != 0 and "Traceback" not in err
    assert not (tmp_path / "o.json").exists()


def test_console_script_trace_relative_paths(tmp_path):
    """End to end through the installed console script, run from another directory."""
    (tmp_path / "scn").mkdir()
    _box([100, 100, 2], (0, 0, -1)).export(tmp_path / "scn" / "plate.stl")
    _scene(tmp_path / "scn" / "plate.toml",
           [{"name": "plate", "mesh": "plate.stl", "material": "grey", "role": "surface"}],
           [BEAM], {"grey": [{"type": "lambertian", "rd": 0.5}]})
    r = run_console(["trace", "scn/plate.toml", "--rays", 2000, "--seed", 1, "--json", "out/res.json"], cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / "out" / "res.json").read_text())
    assert abs(doc["escaped_w"] - 0.5) <= max(4 * doc["escaped_stderr_w"], 1e-9) and doc["escaped_w"] > 0
    r = run_console(["trace", "scn/missing.toml", "--rays", 10, "--json", "x.json"], cwd=tmp_path)
    assert_one_line_error(r.returncode, r.stderr, "missing.toml")
