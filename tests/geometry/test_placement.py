"""Placing parts (CONTRACTS §6.4): ``rotate_deg`` about the origin, then ``translate_mm``; a file used by
many parts is read and meshed once."""
import json

import numpy as np
import pytest
import trimesh

import geometry.io as gio
from geometry.io import load_scene
from geometry.mesh import GeometryError
from geometry.placement import cos_sin_deg, rotation_matrix


def test_rotation_matrix_agrees_with_scipy_for_a_general_axis_and_angle():
    """Independent reference: scipy's Rotation from a rotation vector (angle x unit axis)."""
    from scipy.spatial.transform import Rotation

    axis = np.array([1.0, -2.0, 0.5])
    for angle in (37.0, -123.4, 410.0):
        want = Rotation.from_rotvec(np.radians(angle) * axis / np.linalg.norm(axis)).as_matrix()
        got = rotation_matrix(axis, angle)
        assert np.abs(got - want).max() < 1e-14
        assert np.linalg.det(got) == pytest.approx(1.0, abs=1e-14)


def test_quarter_turns_are_exact():
    assert [cos_sin_deg(a) for a in (0, 90, 180, 270, -90, 450)] == [
        (1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0), (0.0, -1.0), (0.0, 1.0)]
    # (x, y, z) -> (-y, x, z): a quarter turn about +z, right hand, with no 6e-17 noise
    assert np.array_equal(rotation_matrix([0, 0, 1], 90.0), [[0, -1, 0], [1, 0, 0], [0, 0, 1]])


# --- an independent placement for the tests: quarter turns as exact coordinate permutations ---

def _turn(points, axis: str, quarter_turns: int):
    """Points turned by k x 90 deg about a world axis, right hand, by swapping and negating coordinates."""
    p = np.array(points, dtype=np.float64, copy=True)
    i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    for _ in range(quarter_turns % 4):
        p[..., i], p[..., j] = -p[..., j].copy(), p[..., i].copy()
    return p


AXES = {"x": [1.0, 0.0, 0.0], "y": [0.0, 1.0, 0.0], "z": [0.0, 0.0, 1.0]}


def _baffle(tmp_path):
    box = trimesh.creation.box(extents=(30.0, 4.0, 2.0))
    box.apply_translation([6.0, 1.5, 0.25])  # off the origin, so the rotation matters
    box.export(tmp_path / "baffle.ply")
    return np.asarray(box.vertices), np.asarray(box.faces)


def test_one_file_placed_by_many_parts_is_read_once_and_moved_exactly(tmp_path, monkeypatch):
    v, f = _baffle(tmp_path)
    placements = [("z", 1, [133.35, 0.5, -2.0]), ("x", 2, [1.0, 2.0, 3.0]), ("y", 3, [-7.25, 0.125, 40.0])]
    lines = []
    for k, (axis, quarter, shift) in enumerate(placements):
        lines.append(f'[[part]]\nname = "baffle_{k}"\nmesh = "baffle.ply"\nmaterial = "black"\n'
                     f'rotate_deg = {{axis = {AXES[axis]}, angle = {90.0 * quarter}}}\ntranslate_mm = {shift}\n')
    (tmp_path / "scene.toml").write_text("\n".join(lines))
    reads = []
    real = gio._read_mesh
    monkeypatch.setattr(gio, "_read_mesh", lambda *a: reads.append(a) or real(*a))
    scene = load_scene(tmp_path / "scene.toml")
    assert len(reads) == 1
    for part, (axis, quarter, shift) in zip(scene.parts, placements):
        want = _turn(v, axis, quarter) + np.array(shift)
        assert np.array_equal(part.vertices_mm, want), part.name
        assert np.array_equal(part.faces, f)
        # outward normals stay outward: the volume keeps its sign
        assert part.to_trimesh().volume == pytest.approx(30.0 * 4.0 * 2.0, rel=1e-12)
    assert load_scene(tmp_path / "scene.toml") is not scene and len(reads) == 2  # read again by a new load


def test_split_solids_are_all_placed_and_the_step_file_is_meshed_once(tmp_path, monkeypatch):
    step = tmp_path / "bench.step"
    step.write_bytes((gio.Path(__file__).parents[1] / "data" / "cad" / "ocp_bench_m.step").read_bytes())
    monkeypatch.setenv("STRAYLIGHT_CACHE_DIR", str(tmp_path / "cache"))
    (tmp_path / "plain.toml").write_text('[[part]]\nname = "b"\nmesh = "bench.step"\nsplit = "solids"\n')
    plain = load_scene(tmp_path / "plain.toml")
    calls = []
    real = gio._tessellate_cad
    monkeypatch.setattr(gio, "_tessellate_cad", lambda *a: calls.append(a) or real(*a))
    (tmp_path / "placed.toml").write_text(
        '[[part]]\nname = "a"\nmesh = "bench.step"\nsplit = "solids"\n'
        '[[part]]\nname = "b"\nmesh = "bench.step"\nsplit = "solids"\n'
        'rotate_deg = {axis = [0.0, 1.0, 0.0], angle = -90.0}\ntranslate_mm = [10.0, 20.0, 30.0]\n')
    placed = load_scene(tmp_path / "placed.toml")
    assert len(calls) == 1  # two parts, one file, one tolerance: meshed once
    moved = [p for p in placed.parts if p.name.startswith("b/")]
    assert len(moved) == len(plain.parts) >= 2
    for before, after in zip(plain.parts, moved):
        assert after.name == before.name
        assert np.array_equal(after.vertices_mm, _turn(before.vertices_mm, "y", 3) + [10.0, 20.0, 30.0])


def test_an_analytic_surface_is_placed_with_its_axis(tmp_path):
    (tmp_path / "scene.toml").write_text(
        '[[part]]\nname = "m"\nmaterial = "black"\n'
        'surface = {type = "conic", vertex_mm = [1.0, 2.0, 3.0], axis = [0.0, 0.0, 1.0], radius_mm = 100.0, '
        'conic = -1.0, outer_radius_mm = 10.0}\n'
        'rotate_deg = {axis = [1.0, 0.0, 0.0], angle = 90.0}\ntranslate_mm = [0.0, 0.0, 50.0]\n')
    part = load_scene(tmp_path / "scene.toml").parts[0]
    # a quarter turn about +x takes (x, y, z) to (x, -z, y)
    assert np.array_equal(part.surface.vertex_mm, [1.0, -3.0, 52.0])
    assert np.array_equal(part.surface.axis, [0.0, -1.0, 0.0])
    # the mesh is the placed surface's: every vertex on the paraboloid about the new axis
    local = part.surface.to_local(part.vertices_mm)
    assert np.abs(local[:, 2] - part.surface.sag(np.hypot(local[:, 0], local[:, 1]))).max() < 1e-12


@pytest.mark.parametrize("text, words", [
    ('rotate_deg = {axis = [0.0, 0.0, 1.0]}', "rotate_deg must be a table"),
    ('rotate_deg = {axis = [0.0, 0.0, 0.0], angle = 9.0}', "axis must not be zero"),
    ('rotate_deg = {axis = [0.0, 1.0], angle = 9.0}', "rotate_deg axis must be three numbers"),
    ('rotate_deg = {axis = [0.0, 0.0, 1.0], angle = "90"}', "angle must be a number"),
    ('translate_mm = [1.0, 2.0]', "translate_mm must be three numbers"),
])
def test_bad_placement_is_a_one_line_error_naming_the_entry(tmp_path, text, words):
    _baffle(tmp_path)
    (tmp_path / "scene.toml").write_text(f'[[part]]\nname = "b"\nmesh = "baffle.ply"\n{text}\n')
    with pytest.raises(GeometryError) as err:
        load_scene(tmp_path / "scene.toml")
    msg = str(err.value)
    assert words in msg and "[[part]] 1" in msg and "\n" not in msg


SCENE_TAIL = """
[material.grey]
components = [{type = "lambertian", rd = 0.6}]

[[part]]
name = "det"
role = "detector"
surface = {type = "plane", vertex_mm = %s, axis = %s, outer_radius_mm = 12.0}
%s
[[source]]
type = "collimated_disk"
center_mm = [0.0, 0.0, 60.0]
normal = [0.0, 0.0, -1.0]
direction = [0.0, 0.0, -1.0]
radius_mm = 25.0
power_w = 1.0
"""


def test_placed_parts_trace_identically_to_the_parts_pre_transformed(tmp_path):
    """Acceptance: the same seed gives the same JSON numbers whether the parts are placed by
    rotate_deg/translate_mm or written already in place (an independent transform: coordinate swaps)."""
    from straylight.cli.main import main

    v, f = _baffle(tmp_path)
    placements = [("z", 1, [3.0, -1.0, 20.5]), ("x", 2, [-4.0, 2.0, 10.25]), ("z", 3, [0.5, 0.75, 4.0])]
    placed, moved = [], []
    for k, (axis, quarter, shift) in enumerate(placements):
        placed.append(f'[[part]]\nname = "baffle_{k}"\nmesh = "baffle.ply"\nmaterial = "grey"\n'
                      f'rotate_deg = {{axis = {AXES[axis]}, angle = {90.0 * quarter}}}\ntranslate_mm = {shift}\n')
        trimesh.Trimesh(_turn(v, axis, quarter) + np.array(shift), f, process=False).export(
            tmp_path / f"moved_{k}.ply", encoding="binary")
        moved.append(f'[[part]]\nname = "baffle_{k}"\nmesh = "moved_{k}.ply"\nmaterial = "grey"\n')
    # the detector disk: in its own frame at the origin facing +z, turned to face -x... then placed;
    # pre-transformed: a half turn about x takes the axis +z to -z and the vertex (0, 0, 1) to (0, 0, -1)
    det_placed = SCENE_TAIL % ("[0.0, 0.0, 1.0]", "[0.0, 0.0, 1.0]",
                               'rotate_deg = {axis = [1.0, 0.0, 0.0], angle = 180.0}\ntranslate_mm = [0.5, 0.5, 3.0]')
    det_moved = SCENE_TAIL % ("[0.5, 0.5, 2.0]", "[0.0, 0.0, -1.0]", "")
    (tmp_path / "placed.toml").write_text("\n".join(placed) + det_placed)
    (tmp_path / "moved.toml").write_text("\n".join(moved) + det_moved)
    out = {}
    for name in ("placed", "moved"):
        assert main(["trace", str(tmp_path / f"{name}.toml"), "--rays", "3000", "--seed", "11",
                     "--json", str(tmp_path / f"{name}.json")]) == 0
        out[name] = json.loads((tmp_path / f"{name}.json").read_text())
    res = out["placed"]
    assert res["detectors"]["det"]["power_w"] > 0.01  # the geometry couples: scatter off the baffles
    assert sum(a["power_w"] for a in res["absorbed"].values()) > 0.05
    for doc in out.values():
        doc.pop("timing", None)
        doc.pop("seconds", None)
    assert out["placed"] == out["moved"]
