"""Scene TOML (CONTRACTS §6) -> resolved scene, and `straylight trace` (CONTRACTS §4.3)."""
import json

import pytest
import trimesh

from engine_helpers import disk_part
from straylight.cli.main import main
from straylight.scene import SceneFileError, SceneWarning, load_scene


def _write_scene(tmp_path, material_line='material = "grey"', extra_source="", mesh="box.stl"):
    box = trimesh.creation.box(extents=(40.0, 40.0, 2.0))  # closed solid floor, top face at z = 1
    box.export(tmp_path / "box.stl")
    det = disk_part("det", 20.0, 10.0, 128)
    det.to_trimesh().export(tmp_path / "det.ply")
    (tmp_path / "scene.toml").write_text(f"""
[material.grey]
components = [{{type = "lambertian", rd = 0.5}}]

[[part]]
name = "floor"
mesh = "{mesh}"
{material_line}
role = "surface"

[[part]]
name = "det"
mesh = "det.ply"
role = "detector"

[[source]]
type = "collimated_disk"
center_mm = [0.0, 0.0, 30.0]
normal = [0.0, 0.0, -1.0]
direction = [0.0, 0.0, -1.0]
radius_mm = 5.0
power_w = 2.0
{extra_source}
""")
    return tmp_path / "scene.toml"


def test_scene_file_resolves_parts_materials_and_sources(tmp_path):
    rs = load_scene(_write_scene(tmp_path))
    assert rs.scene.part_names == ("floor", "det")
    assert set(rs.materials) == {"grey"}
    assert len(rs.sources) == 1 and rs.sources[0].power_w == 2.0
    assert rs.warnings == ()


def test_trace_cli_writes_the_contract_json(tmp_path):
    """The beam crosses the (two-sided) detector disk before it can reach the floor, so all of
    its 2 W are detected, with no scatter at all."""
    scene = _write_scene(tmp_path)
    out = tmp_path / "out" / "res.json"
    assert main(["trace", str(scene), "--rays", "4000", "--seed", "3", "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    for key in ("rays", "seed", "emitted_w", "detectors", "absorbed", "escaped_w", "escaped_stderr_w"):
        assert key in res
    assert res["rays"] == 4000 and res["seed"] == 3 and res["emitted_w"] == 2.0
    det = res["detectors"]["det"]
    assert det["power_w"] > 0 and det["stderr_w"] >= 0
    total = det["power_w"] + sum(v["power_w"] for v in res["absorbed"].values()) + res["escaped_w"]
    assert abs(total - res["emitted_w"]) < 1e-9 * res["emitted_w"]
    # the beam goes through the detector disk first: all 2 W are detected directly
    assert det["power_w"] == pytest.approx(2.0, rel=1e-12)


def test_trace_cli_same_seed_same_json(tmp_path):
    scene = _write_scene(tmp_path, extra_source="""
[[source]]
type = "point"
center_mm = [0.0, 0.0, 10.0]
power_w = 1.0
""")
    outs = []
    for batch in ("1000", "3000"):
        out = tmp_path / f"r{batch}.json"
        assert main(["trace", str(scene), "--rays", "6000", "--seed", "9", "--json", str(out),
                     "--batch-rays", batch]) == 0
        outs.append(json.loads(out.read_text()))
    assert outs[0]["detectors"]["det"]["power_w"] > 0
    assert outs[0] == outs[1]


def test_missing_mesh_names_the_file(tmp_path, capsys):
    scene = _write_scene(tmp_path, mesh="nothere.stl")
    with pytest.raises(ValueError, match="nothere.stl"):
        load_scene(scene)
    assert main(["trace", str(scene), "--rays", "10", "--json", str(tmp_path / "x.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert "nothere.stl" in err and len(err.splitlines()) == 1


def test_unknown_material_lists_the_known_ones(tmp_path):
    scene = _write_scene(tmp_path, material_line='material = "gery"')
    with pytest.raises(SceneFileError, match=r"unknown material 'gery'; known: grey"):
        load_scene(scene)


def test_material_preset_and_file_paths(tmp_path):
    (tmp_path / "mat.json").write_text(json.dumps({"name": "m", "components": [{"type": "lambertian", "rd": 0.1}]}))
    rs = load_scene(_write_scene(tmp_path, material_line='material = "mat.json"'))
    assert list(rs.materials) == ["mat.json"]
    rs = load_scene(_write_scene(tmp_path, material_line='material = "z307"'))
    assert list(rs.materials) == ["z307"]


def test_surface_without_material_is_an_error(tmp_path):
    with pytest.raises(SceneFileError, match="needs a material"):
        load_scene(_write_scene(tmp_path, material_line=""))


def test_bad_source_key_is_an_error(tmp_path):
    scene = _write_scene(tmp_path, extra_source="""
[[source]]
type = "point"
position_mm = [0.0, 0.0, 10.0]
colour = "red"
""")
    with pytest.raises(SceneFileError, match=r"\[\[source\]\] 2: unknown key\(s\) colour"):
        load_scene(scene)


def test_warnings_for_open_mesh_and_a_source_that_misses(tmp_path):
    scene = _write_scene(tmp_path, extra_source="""
[[source]]
type = "collimated_disk"
center_mm = [0.0, 0.0, 100.0]
normal = [0.0, 0.0, 1.0]
direction = [0.0, 0.0, 1.0]
radius_mm = 1.0
""")
    open_floor = trimesh.creation.box(extents=(40.0, 40.0, 2.0))
    open_floor = trimesh.Trimesh(open_floor.vertices, open_floor.faces[:-2], process=False)
    open_floor.export(tmp_path / "box.stl")
    text = scene.read_text()
    with pytest.warns(SceneWarning) as rec:
        rs = load_scene(scene)
    messages = " ".join(str(w.message) for w in rec)
    assert "not watertight" in messages and "[[source]] 2" in messages
    assert len(rs.warnings) == 2 and text == scene.read_text()
