"""Bounds where data enter: magnitudes that float arithmetic cannot carry are refused in one
line naming the limit (exit 2, no traceback), before any ray is traced. Each case failed on main
13a6b5b (silently biased results, NaN, 0 W, or a cryptic Python message)."""
from __future__ import annotations

import json

import pytest

from straylight.cli.main import main
from tests.hostile.conftest import scene_text
from tests.validation.thermal_scenes import part, plane, write_scene


def _one_error_line(capsys) -> str:
    err = [line for line in capsys.readouterr().err.strip().splitlines() if "warning" not in line]
    assert len(err) == 1, err
    assert err[0].startswith("straylight: error: ") and "Traceback" not in err[0]
    return err[0]


def _trace(tmp_path, text: str, *extra) -> int:
    path = tmp_path / "scene.toml"
    path.write_text(text)
    return main(["trace", str(path), "--rays", "2000", "--json", str(tmp_path / "out.json"), *extra])


def _far(text: str, part_name: str, z_mm: float) -> str:
    return text.replace(f'name = "{part_name}"', f'name = "{part_name}"\ntranslate_mm = [0.0, 0.0, {z_mm!r}]')


@pytest.mark.parametrize("z_mm, limit", [
    (1e6, "self-intersection offset is 2 mm"),  # 32 float32 ulps at 1e6 mm: 0.7 of the 2.8 mm part
    (1e9, "beyond the 1e+07 mm (10 km)"),  # every detector read 0 W on main
])
def test_far_part_refused(tmp_path, capsys, z_mm, limit):
    assert _trace(tmp_path, _far(scene_text(), "dark", z_mm)) == 2
    line = _one_error_line(capsys)
    assert limit in line and ("'dark'" in line or "[[part]] 3" in line)
    assert not (tmp_path / "out.json").exists()


def test_moderately_far_part_warned(tmp_path, capsys):
    """1e5 mm: offset 0.25 mm (32 ulps of float32 at 1e5 = 32 x 2^-7 mm), 9 % of the 2.8 mm part: traced, warned."""
    assert _trace(tmp_path, _far(scene_text(), "dark", 1e5)) == 0
    err = capsys.readouterr().err
    assert "warning: part 'dark' reaches 1e+05 mm" in err and "offset is 0.25 mm" in err


def test_near_scene_not_warned(tmp_path, capsys):
    assert _trace(tmp_path, scene_text()) == 0
    assert "warning" not in capsys.readouterr().err


@pytest.mark.parametrize("det_r, key", [(1e30, "outer_radius_mm"), (2e7, "outer_radius_mm")])
def test_huge_radius_refused(tmp_path, capsys, det_r, key):
    assert _trace(tmp_path, scene_text(det_r=det_r)) == 2  # main: "float division by zero"
    line = _one_error_line(capsys)
    assert key in line and "10 km" in line


def test_huge_vertex_refused(tmp_path, capsys):
    text = scene_text().replace("vertex_mm = [0.0, 0.0, 500.0]", "vertex_mm = [0.0, 0.0, 5e8]")
    assert _trace(tmp_path, text) == 2
    assert "surface 'vertex_mm' = 5e+08 mm is beyond" in _one_error_line(capsys)


@pytest.mark.parametrize("power_w", [1e308, 1e31])
def test_huge_power_refused(tmp_path, capsys, power_w):
    assert _trace(tmp_path, scene_text(power_w=power_w)) == 2  # main: NaN stderr with exit 0
    assert "power_w" in (line := _one_error_line(capsys)) and "1e+30 W" in line


def test_large_power_still_traced(tmp_path):
    assert _trace(tmp_path, scene_text(power_w=1e20)) == 0


@pytest.mark.parametrize("name", ["", " ", "a\x00b", "tab\there"])
def test_bad_part_names_refused(tmp_path, capsys, name):
    text = scene_text().replace('name = "dark"', f"name = {json.dumps(name)}")  # TOML reads \\u0000
    assert _trace(tmp_path, text) == 2
    assert "part name" in _one_error_line(capsys)


@pytest.fixture
def hot_scene(tmp_path):
    def make(t_k):
        text = part("focal_plane", role="detector", temperature_k=77.0, surface=plane((0, 0, 0), (0, 0, 1), 5.0))
        text += part("baffle", "black", t_k, surface=plane((0, 0, 30), (0, 0, -1), 20.0))
        return write_scene(tmp_path, text)
    return make


def test_scene_temperature_above_limit_refused(tmp_path, capsys, hot_scene):
    path = hot_scene(1e9)  # main: 0 W and "rays": 0
    assert main(["thermal", str(path), "--band-um", "8", "12", "--rays", "2000", "--out", str(tmp_path / "o")]) == 2
    line = _one_error_line(capsys)
    assert "temperature_k = 1e+09 K is above the 100000 K limit" in line


def test_cli_temperature_above_limit_refused(tmp_path, capsys, hot_scene):
    path = hot_scene(300.0)
    assert main(["thermal", str(path), "--band-um", "8", "12", "--rays", "2000", "--temperature-k", "baffle=1e300",
                 "--out", str(tmp_path / "o")]) == 2  # main: "invalid index to scalar variable."
    assert "baffle=1e300" in (line := _one_error_line(capsys)) and "100000 K limit" in line


def test_paths_top_below_one_refused(tmp_path, capsys, scene):
    out = tmp_path / "p"
    assert main(["paths", str(scene), "--angle-deg", "0", "--rays", "1000", "--top", "-1", "--out", str(out)]) == 2
    assert "--top must be >= 1" in _one_error_line(capsys)  # main: accepted, a table without its last row


def test_view_rays_beyond_a_picture_refused(tmp_path, capsys, scene):
    png = tmp_path / "v.png"
    assert main(["view", str(scene), "--rays", "1e9", "--png", str(png)]) == 2  # main: "Unable to allocate 29.8 GiB"
    assert "--rays 1000000000 is above 100000" in _one_error_line(capsys)
    assert not png.exists()


def test_material_with_too_many_components_refused_fast(tmp_path, capsys):
    import time

    from materials import MaterialError, load_material

    doc = {"name": "many", "components": [{"type": "lambertian", "rd": 1e-6}] * 100_000}
    start = time.perf_counter()
    with pytest.raises(MaterialError, match="100000 components is above 64"):
        load_material(doc)
    assert time.perf_counter() - start < 1.0  # main: minutes
