"""STEP/IGES from writers other than this project's export path load, keep their names and units,
tessellate within tolerance (measured generically), and trace with an exact power balance.

The files are in tests/data/cad/ (made by make_cad_files.py there: gmsh's OpenCASCADE build, OCP's
XDE writers in inch and metre, IGES, CadQuery); the ground truth below is their construction.
"""
from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from geometry.cad import read_cad, unique_names
from geometry.io import load_cad_parts, load_part, load_scene
from geometry.mesh import GeometryError

DATA = Path(__file__).resolve().parents[1] / "data" / "cad"
# products name the solids (CONTRACTS 6.2); "housing" and "lens_1" are the instance names (aliases)
BENCH = ["housing_product", "lens_product", "vane", "vane_2", "bspline_revolved", "offset_shell", "solid7", "detector"]
NAMES = {
    "gmsh_parts.step": [f"solid{k}" for k in range(1, 7)],
    "gmsh_parts.iges": [f"solid{k}" for k in range(1, 7)],
    "ocp_bench_inch.step": BENCH,
    "ocp_bench_m.step": BENCH,
    "ocp_bench.iges": ["bench"] + [f"bench_{k}" for k in range(2, 9)],  # IGES keeps one name for the file
    "cq_features.step": ["spline_sweep", "ellipse_boss", "torus", "filleted_block", "detector"],
}
TOL = 0.05


def _types(shape):
    from OCP.BRepAdaptor import BRepAdaptor_Curve, BRepAdaptor_Surface
    from OCP.TopAbs import TopAbs_EDGE, TopAbs_FACE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    kinds = Counter()
    for what, adaptor, cast in ((TopAbs_FACE, BRepAdaptor_Surface, TopoDS.Face_s),
                                (TopAbs_EDGE, BRepAdaptor_Curve, TopoDS.Edge_s)):
        explorer = TopExp_Explorer(shape, what)
        while explorer.More():
            kinds[str(adaptor(cast(explorer.Current())).GetType()).split("_")[-1]] += 1
            explorer.Next()
    return kinds


@pytest.mark.parametrize("file", sorted(NAMES))
def test_files_load_with_their_solid_names(file):
    solids = read_cad(DATA / file)
    assert [s.name for s in solids] == NAMES[file]
    assert all(s.kind == "solid" for s in solids)


def test_the_files_hold_every_kind_of_curve_and_surface():
    """The set is worth testing: B-spline, ellipse, torus, offset, revolution, extrusion surfaces/curves."""
    kinds = Counter()
    for file in NAMES:
        for s in read_cad(DATA / file):
            kinds.update(_types(s.shape))
    for kind in ("BSplineCurve", "Ellipse", "Circle", "BSplineSurface", "Torus", "OffsetSurface",
                 "SurfaceOfRevolution", "SurfaceOfExtrusion", "Sphere", "Cone", "Cylinder"):
        assert kinds[kind] > 0, kind


@pytest.mark.parametrize("file", sorted(NAMES))
def test_every_solid_tessellates_within_tolerance_watertight(file):
    parts = load_cad_parts(DATA / file, name="x", tolerance_mm=TOL)
    assert [p.name for p in parts] == [f"x/{n}" for n in NAMES[file]]
    for part in parts:
        report = part.meta["tessellation"]
        assert 0 <= report.max_chord_error_mm <= TOL, (part.name, report)
        mesh = part.to_trimesh()
        assert mesh.is_watertight and mesh.volume > 0, part.name
    assert max(p.meta["tessellation"].max_chord_error_mm for p in parts) > TOL / 10  # curved faces measured


def test_units_inch_and_metre_files_give_the_same_millimetres():
    """ocp_bench_inch.step and ocp_bench_m.step hold the same model (vane: r 20..29.9 mm, 1 mm thick,
    at z = 20 and 40; housing z = 0..60): the reader must convert both to mm."""
    inch = {p.name: p for p in load_cad_parts(DATA / "ocp_bench_inch.step", name="a", tolerance_mm=TOL)}
    metre = {p.name: p for p in load_cad_parts(DATA / "ocp_bench_m.step", name="a", tolerance_mm=TOL)}
    for parts in (inch, metre):
        v = parts["a/vane_2"].vertices_mm
        r = np.hypot(v[:, 0], v[:, 1])
        assert r.max() == pytest.approx(29.9, abs=1e-6) and r.min() == pytest.approx(20.0, abs=1e-6)
        assert (v[:, 2].min(), v[:, 2].max()) == pytest.approx((40.0, 41.0), abs=1e-6)
        z = parts["a/housing_product"].vertices_mm[:, 2]
        assert (z.min(), z.max()) == pytest.approx((0.0, 60.0), abs=1e-6)
    assert np.allclose(inch["a/lens_product"].vertices_mm, metre["a/lens_product"].vertices_mm, atol=1e-6)
    # IGES written in inch: same mm
    iges = {p.name: p for p in load_cad_parts(DATA / "ocp_bench.iges", name="a", tolerance_mm=TOL)}
    r = np.hypot(*iges["a/bench_4"].vertices_mm[:, :2].T)
    assert r.max() == pytest.approx(29.9, abs=1e-5)


def test_volumes_against_analytic_formulas():
    """gmsh file: torus R 15 r 2 (2 pi^2 R r^2), sphere r 5, cone frustum r 8 -> 3 over 10 mm; the mesh
    is inscribed, so it may be smaller by at most tolerance x area (and is not larger)."""
    parts = {p.name: p.to_trimesh() for p in load_cad_parts(DATA / "gmsh_parts.step", name="g", tolerance_mm=TOL)}
    exact = {"g/solid2": 2 * np.pi**2 * 15 * 2**2, "g/solid5": 4 / 3 * np.pi * 5**3,
             "g/solid6": np.pi * 10 / 3 * (8**2 + 8 * 3 + 3**2)}
    for name, volume in exact.items():
        mesh = parts[name]
        assert 0 <= volume - mesh.volume <= TOL * mesh.area, name


def test_chord_error_of_a_third_party_torus_against_dense_analytic_distance():
    """The reported error is measured on the B-rep's own parametrisation; check it against
    | sqrt((rho - R)^2 + (z - z0)^2) - r | at 66 points per triangle (R 15, r 2, z0 20)."""
    part = load_part(DATA / "gmsh_parts.step", tolerance_mm=0.02)  # whole file; take the torus's triangles
    tri = part.vertices_mm[part.faces]
    centre = tri.mean(axis=1)
    torus = tri[np.abs(centre[:, 2] - 20) < 2.5]
    n = 10
    w = np.array([(i, j, n - i - j) for i in range(n + 1) for j in range(n + 1 - i)]) / n
    p = np.einsum("kj,mjc->mkc", w, torus).reshape(-1, 3)
    dense = np.abs(np.hypot(np.hypot(p[:, 0], p[:, 1]) - 15, p[:, 2] - 20) - 2).max()
    report = part.meta["tessellation"]
    assert dense > 0.002
    assert dense <= report.max_chord_error_mm * (1 + 1e-3) <= 0.02 * (1 + 1e-3)


def _scene(tmp_path, file, detector, extra=""):
    toml = tmp_path / "scene.toml"
    toml.write_text(f"""
[[part]]
name = "cad"
mesh = "{DATA / file}"
split = "solids"
tolerance_mm = 0.1
material = "z302_sample_b"
[part.solids."{detector}"]
role = "detector"
{extra}
[[source]]
type = "collimated_disk"
center_mm = [3.0, 2.0, 150.0]
normal = [0.0, 0.0, -1.0]
direction = [0.05, 0.02, -0.9985"]
radius_mm = 40.0
power_w = 1.0
""".replace('-0.9985"', "-0.9985"))
    return toml


@pytest.mark.parametrize("file, detector", [("gmsh_parts.step", "solid1"), ("ocp_bench_inch.step", "detector"),
                                            ("cq_features.step", "detector"), ("gmsh_parts.iges", "solid1")])
def test_trace_power_balance(tmp_path, file, detector):
    import warnings

    from straylight.scene import load_scene as resolve

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rs = resolve(_scene(tmp_path, file, detector))
    assert rs.scene.part(f"cad/{detector}").role == "detector"
    result = rs.trace(3000, seed=2)
    assert abs(result.ledger["balance_residual_w"]) < 1e-9
    hit = sum(t.power_w for t in result.absorbed.values()) + sum(t.power_w for t in result.detectors.values())
    assert hit > 0.05  # the beam does meet the parts


def test_per_solid_overrides_and_unknown_names(tmp_path):
    toml = _scene(tmp_path, "ocp_bench_m.step", "detector", '[part.solids."vane_2"]\nmaterial = "z307"\n'
                  'role = "absorber"\n')
    scene = load_scene(toml)
    assert [p.name for p in scene.parts] == [f"cad/{n}" for n in BENCH]
    vane = scene.part("cad/vane_2")
    assert (vane.material, vane.role) == ("z307", "absorber")
    assert (scene.part("cad/vane").material, scene.part("cad/vane").role) == ("z302_sample_b", "surface")
    bad = _scene(tmp_path, "ocp_bench_m.step", "lens_7")
    with pytest.raises(GeometryError, match=r"no solid named 'lens_7'.*lens_1.*detector"):
        load_scene(bad)
    bad.write_text(bad.read_text().replace('split = "solids"', 'split = "faces"'))
    with pytest.raises(GeometryError, match="split must be one of"):
        load_scene(bad)


def test_broken_files_give_one_line_errors_naming_the_file(tmp_path):
    good = (DATA / "cq_features.step").read_text()
    truncated = tmp_path / "truncated.step"
    truncated.write_text(good[: len(good) // 3])
    garbage = tmp_path / "garbage.stp"
    garbage.write_text("this is not a STEP file\n")
    empty = tmp_path / "empty.igs"
    empty.write_text("")
    for path in (truncated, garbage, empty, tmp_path / "missing.step"):
        with pytest.raises(GeometryError) as info:
            load_part(path)
        message = str(info.value)
        assert str(path) in message and "\n" not in message


def test_unique_names_rule():
    assert unique_names(["a", None, "a", "b", "a", None]) == ["a", "solid2", "a_2", "b", "a_3", "solid6"]
    assert unique_names(["a", "a", "a_2"]) == ["a", "a_3", "a_2"]


def test_geometry_check_lists_every_solid(tmp_path, capsys):
    from straylight.cli.main import main

    toml = _scene(tmp_path, "cq_features.step", "detector")
    assert main(["geometry", "check", str(toml)]) == 0
    out = capsys.readouterr().out
    for name in NAMES["cq_features.step"]:
        assert f"cad/{name} " in out
    assert "total" in out and "(5 parts)" in out


def test_geometry_scene_command_writes_a_traceable_scene(tmp_path, capsys):
    """`straylight geometry scene` on a third-party STEP: one part per solid, the detector marked, a
    beam along -z from above the assembly covering all of it (every vertex within the disk's radius)."""
    from straylight.cli.main import main
    from straylight.scene import load_scene as resolve

    toml = tmp_path / "sub" / "bench.toml"
    toml.parent.mkdir()
    assert main(["geometry", "scene", str(DATA / "ocp_bench_m.step"), "-o", str(toml), "--tolerance-mm", "0.1"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"ocp_bench_m/detector +detector", out) and "8 parts" in out
    rs = resolve(toml)
    assert [p.name for p in rs.scene.parts] == [f"ocp_bench_m/{n}" for n in BENCH]
    assert rs.scene.part("ocp_bench_m/detector").role == "detector"
    (source,) = rs.sources
    v = np.concatenate([p.vertices_mm for p in rs.scene.parts])
    c = source.center_mm
    assert np.hypot(v[:, 0] - c[0], v[:, 1] - c[1]).max() <= source.radius_mm and c[2] > v[:, 2].max()
    result = rs.trace(2000, seed=3)
    assert abs(result.ledger["balance_residual_w"]) < 1e-9 and result.detectors["ocp_bench_m/detector"].power_w > 0
    # no solid named "detector": the scene is written without one (tests/geometry/test_cad_scene_detector.py)
    assert main(["geometry", "scene", str(DATA / "gmsh_parts.step"), "-o", str(tmp_path / "g.toml")]) == 0
    assert "no detector yet" in capsys.readouterr().out


def test_instances_of_one_product_share_one_mesh():
    """ocp_bench places product "vane" twice (z = 20 and 40): one mesh, moved rigidly by 20 mm."""
    parts = {p.name: p for p in load_cad_parts(DATA / "ocp_bench_m.step", name="a", tolerance_mm=TOL)}
    a, b = parts["a/vane"], parts["a/vane_2"]
    assert np.array_equal(a.faces, b.faces)
    assert np.allclose(b.vertices_mm - a.vertices_mm, [0.0, 0.0, 20.0], atol=1e-9)
    assert a.meta["tessellation"].max_chord_error_mm == b.meta["tessellation"].max_chord_error_mm
