"""Scene-file keys of CONTRACTS §6.1 and §6.3: ``surface = {...}``, ``back_material`` and a source's
``polarization`` / ``e_field``; each bad value is a one-line error naming the file and entry."""
import textwrap

import numpy as np
import pytest

from straylight.polarization import UNPOLARIZED
from straylight.scene import SceneFileError, load_scene

HEAD = """
[material.black]
components = [{type = "lambertian", rd = 0.05}]
[material.grey]
components = [{type = "lambertian", rd = 0.5}]
"""
SOURCE = """
[[source]]
type = "collimated_disk"
center_mm = [0.0, 0.0, 300.0]
normal = [0.0, 0.0, -1.0]
direction = [0.0, 0.0, -1.0]
radius_mm = 50.0
"""


def _write(tmp_path, text):
    p = tmp_path / "scene.toml"
    p.write_text(textwrap.dedent(text))
    return p


def test_analytic_part_and_back_material(tmp_path):
    p = _write(tmp_path, HEAD + """
[[part]]
name = "primary"
surface = {type = "conic", vertex_mm = [0.0, 0.0, 0.0], axis = [0.0, 0.0, 1.0], radius_mm = 2000.0, conic = -1.0, outer_radius_mm = 100.0, inner_radius_mm = 20.0}
material = "grey"
back_material = "black"
tolerance_mm = 0.05
[[part]]
name = "det"
surface = {type = "plane", vertex_mm = [0.0, 0.0, 1000.0], axis = [0.0, 0.0, -1.0], outer_radius_mm = 1.0}
role = "detector"
""" + SOURCE + 'polarization = "linear"\ne_field = [0.0, 2.0, 0.0]\n')
    rs = load_scene(p, check_watertight=False)
    prim = rs.scene.part("primary")
    assert prim.surface.kind == "conic" and prim.back_material == "black"
    assert set(rs.materials) == {"grey", "black"}
    z = prim.vertices_mm[:, 2]
    rho = np.hypot(prim.vertices_mm[:, 0], prim.vertices_mm[:, 1])
    np.testing.assert_allclose(z, rho**2 / 4000, atol=1e-12)  # mesh vertices lie on the sag
    pol = rs.sources[0].polarization
    assert pol.kind == "linear" and pol.e_field == (0.0, 1.0, 0.0)


def test_sources_default_to_unpolarized(tmp_path):
    p = _write(tmp_path, HEAD + """
[[part]]
name = "flat"
surface = {type = "plane", outer_radius_mm = 60.0}
material = "black"
""" + SOURCE)
    assert load_scene(p, check_watertight=False).sources[0].polarization == UNPOLARIZED


@pytest.mark.parametrize("part_extra, source_extra, message", [
    ('surface = {type = "plane", outer_radius_mm = 60.0, tilt = 1}\nmaterial = "black"', "", "unknown surface key"),
    ('surface = {type = "plane", outer_radius_mm = 60.0}\nmaterial = "black"\nback_material = "nope"', "",
     "unknown material 'nope'"),
    ('mesh = "x.stl"\nmaterial = "black"\nback_material = "grey"', "", "back_material' needs an analytic"),
    ('surface = {type = "plane", outer_radius_mm = 60.0}\nmaterial = "black"', 'polarization = "circular"',
     "polarization must be one of"),
    ('surface = {type = "plane", outer_radius_mm = 60.0}\nmaterial = "black"', 'polarization = "linear"',
     "needs e_field"),
    ('surface = {type = "plane", outer_radius_mm = 60.0}\nmaterial = "black"',
     'polarization = "linear"\ne_field = [0.0, 0.6, 0.8]', "normal to the source direction"),
    ('surface = {type = "plane", outer_radius_mm = 60.0}\nmaterial = "black"', 'e_field = [1.0, 0.0, 0.0]',
     "only for polarization"),
])
def test_bad_optics_keys_are_one_line_errors(tmp_path, part_extra, source_extra, message):
    p = _write(tmp_path, HEAD + '[[part]]\nname = "flat"\n' + part_extra + "\n" + SOURCE + source_extra + "\n")
    with pytest.raises(SceneFileError, match=message) as exc:
        load_scene(p, check_watertight=False)
    assert str(p) in str(exc.value) and "\n" not in str(exc.value)
