"""Shared inputs of the hostile-input suite: a small analytic scene that traces in
well under a second, written into the test's own tmp_path (never a real device or shared folder)."""
from __future__ import annotations

import pytest

SCENE = """
[[part]]
name = "wall"
surface = {{type = "cylinder", vertex_mm = [0.0, 0.0, 0.0], axis = [0.0, 0.0, 1.0], radius_mm = 30.0, length_mm = 100.0}}
material = "z302_sample_a"

[[part]]
name = "detector"
role = "detector"
surface = {{type = "plane", vertex_mm = [0.0, 0.0, 0.0], axis = [0.0, 0.0, 1.0], outer_radius_mm = {det_r}}}

[[part]]
name = "dark"
role = "detector"
surface = {{type = "plane", vertex_mm = [0.0, 0.0, 500.0], axis = [0.0, 0.0, 1.0], outer_radius_mm = 1.0}}

[[source]]
type = "collimated_disk"
center_mm = [0.0, 0.0, 110.0]
normal = [0.0, 0.0, -1.0]
direction = [0.0, 0.0, -1.0]
radius_mm = 30.0
power_w = {power_w}

[analysis]
detector = "detector"
entrance = {{center_mm = [0.0, 0.0, 100.0], normal = [0.0, 0.0, 1.0], radius_mm = 30.0}}
"""


def scene_text(det_r: float = 10.0, power_w: float = 1.0) -> str:
    return SCENE.format(det_r=det_r, power_w=power_w)


@pytest.fixture
def scene(tmp_path):
    path = tmp_path / "scene.toml"
    path.write_text(scene_text())
    return path
