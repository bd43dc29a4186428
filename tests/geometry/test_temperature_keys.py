"""``temperature_k`` in scene files (CONTRACTS §7): per part, per solid override, checked."""
from pathlib import Path

import pytest

from geometry.io import load_scene
from geometry.mesh import GeometryError

DATA = Path(__file__).resolve().parents[1] / "data" / "cad"


def test_part_temperature_and_solid_override(tmp_path):
    toml = tmp_path / "scene.toml"
    toml.write_text(f"""
[[part]]
name = "cad"
mesh = "{DATA / 'ocp_bench_inch.step'}"
split = "solids"
material = "z302_sample_b"
temperature_k = 293.15
[part.solids."detector"]
role = "detector"
temperature_k = 77.0
[[part]]
name = "disk"
surface = {{type = "plane", vertex_mm = [0, 0, 500], axis = [0, 0, -1], outer_radius_mm = 5.0}}
role = "absorber"
""")
    scene = load_scene(toml)
    temps = {p.name: p.meta.get("temperature_k") for p in scene.parts}
    assert temps["cad/detector"] == 77.0
    others = [t for n, t in temps.items() if n.startswith("cad/") and n != "cad/detector"]
    assert others and all(t == 293.15 for t in others)
    assert temps["disk"] is None


@pytest.mark.parametrize("value", ["-1.0", '"hot"', "true", "nan"])
def test_bad_temperature_is_named(tmp_path, value):
    toml = tmp_path / "scene.toml"
    toml.write_text(f"""
[[part]]
name = "disk"
surface = {{type = "plane", vertex_mm = [0, 0, 0], axis = [0, 0, 1], outer_radius_mm = 5.0}}
role = "absorber"
temperature_k = {value}
""")
    with pytest.raises(GeometryError, match=r"\[\[part\]\] 1: temperature_k must be a number >= 0"):
        load_scene(toml)
