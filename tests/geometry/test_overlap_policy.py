"""The overlap policy of CONTRACTS 6.2: `geometry check` reports each overlap's volume and depth; an interference of
opaque parts shallower than the chord tolerance is listed and exits 0; a detector, a dielectric part or a depth
beyond the tolerance exits 1. Golden values: unit cubes overlapping by a slab of thickness t have intersection
volume t mm^3 and depth t mm (by construction)."""
import subprocess
import sys
import warnings

import numpy as np
import pytest
import trimesh

from geometry.checks import GeometryWarning, check_scene
from geometry.mesh import Part, Scene


def box(name, dx=0.0, **kw):
    m = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    return Part(name, np.asarray(m.vertices) + (dx, 0.0, 0.0), np.asarray(m.faces), **kw)


@pytest.mark.parametrize("t", [0.02, 0.3])
def test_volume_and_depth_of_a_slab_overlap(t):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = check_scene(Scene((box("a"), box("b", dx=1.0 - t))))
    (o,) = result.overlaps
    assert o.volume_mm3 == pytest.approx(t, rel=1e-9)
    assert o.depth_mm == pytest.approx(t, rel=1e-6)
    assert o.tolerance_mm == 0.05  # no tessellation report: the default chord tolerance
    assert o.changes_trace is (t > 0.05)
    assert result.ok is (t <= 0.05)
    assert f"depth {t:.3g} mm" in result.format()


def test_shallow_overlap_of_opaque_parts_is_silent_but_not_with_a_detector_or_glass():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a harmless interference warns of nothing
        assert check_scene(Scene((box("a"), box("b", dx=0.98)))).ok
    with pytest.warns(GeometryWarning, match=r"'a' and 'b' overlap .*\(b is a detector"):
        result = check_scene(Scene((box("a"), box("b", dx=0.98, role="detector"))))
    assert result.overlaps[0].changes_trace
    with pytest.warns(GeometryWarning, match=r"a is transparent \(dielectric\)"):
        assert not check_scene(Scene((box("a"), box("b", dx=0.98))), transparent={"a"}).ok


def _scene(tmp_path, dx: float, glass: bool = False):
    for name, shift in (("a", 0.0), ("b", dx)):
        m = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
        m.apply_translation((shift, 0.0, 0.0))
        m.export(tmp_path / f"{name}.stl")
    toml = tmp_path / "scene.toml"
    toml.write_text('[material.glass]\ncomponents = [{type = "dielectric", n = 1.5}]\n'
                    '[[part]]\nname = "a"\nmesh = "a.stl"\nmaterial = "' + ("glass" if glass else "z307") + '"\n'
                    '[[part]]\nname = "b"\nmesh = "b.stl"\nmaterial = "z307"\n')
    return toml


def _check(path):
    return subprocess.run([sys.executable, "-c", "import sys; from straylight.cli.main import main; sys.exit(main())",
                           "geometry", "check", str(path)], capture_output=True, text=True, timeout=300)


def test_cli_exit_codes_follow_the_policy(tmp_path):
    shallow = _check(_scene(tmp_path, 0.98))
    assert shallow.returncode == 0, shallow.stdout + shallow.stderr
    assert "overlap a / b: 0.02 mm^3, depth 0.02 mm (opaque parts within the chord tolerance" in shallow.stdout
    deep = _check(_scene(tmp_path, 0.7))
    assert deep.returncode == 1 and "deeper than the chord tolerance" in deep.stderr
    glass = _check(_scene(tmp_path, 0.98, glass=True))
    assert glass.returncode == 1 and "a is transparent (dielectric)" in glass.stderr, glass.stdout + glass.stderr


def test_check_and_errors_take_a_cad_file_directly(tmp_path):
    from pathlib import Path

    step = Path(__file__).resolve().parents[1] / "data" / "cad" / "fusion_like_scope.step"
    out = _check(step)
    assert out.returncode == 0, out.stdout + out.stderr
    assert any(line.startswith("fusion_like_scope/ar0130 v4 ") and "(also: ar0130 v4:1)" in line
               for line in out.stdout.splitlines()), out.stdout
    bad = tmp_path / "scene.toml"
    bad.write_text("ISO-10303-21;\nHEADER;\n")
    out = _check(bad)
    assert out.returncode == 2 and "reading it as TOML" in out.stderr and "Traceback" not in out.stderr


def test_view_takes_a_cad_file_directly(tmp_path):
    from pathlib import Path

    from PIL import Image

    step = Path(__file__).resolve().parents[1] / "data" / "cad" / "fusion_like_scope.step"
    png = tmp_path / "parts.png"
    out = subprocess.run([sys.executable, "-c", "import sys; from straylight.cli.main import main; sys.exit(main())",
                          "view", str(step), "--png", str(png)], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0 and f"written {png}" in out.stdout, out.stdout + out.stderr
    assert Image.open(png).size == (1200, 800)


def test_a_mesh_that_stopped_short_is_held_to_the_error_it_reached():
    """Two touching faces of a stalled B-spline mesh (0.31 mm reached, 0.05 mm asked) overlap by up to the error
    reached: an overlap 0.2 mm deep between such opaque parts is harmless; with 0.05 mm reached it is not."""
    from dataclasses import replace

    from geometry.tessellate import TessellationReport

    report = TessellationReport("a", 0.05, 10.0, 12, 8, 6, 0.31, "sampled", 0.05, 0, "stalled", "")
    a = box("a")
    a = Part("a", a.vertices_mm, a.faces, meta={"tessellation": report})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        (o,) = check_scene(Scene((a, box("b", dx=0.8)))).overlaps
        assert o.tolerance_mm == pytest.approx(0.31) and not o.changes_trace
        tight = Part("a", a.vertices_mm, a.faces, meta={"tessellation": replace(report, max_chord_error_mm=0.04)})
        (o,) = check_scene(Scene((tight, box("b", dx=0.8)))).overlaps
    assert o.tolerance_mm == 0.05 and o.changes_trace
