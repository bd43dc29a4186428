"""Effective emissivity of isothermal diffuse cylindrical cavities: a cold black
detector filling the opening reads eps_a pi B_band(T). Reference: the net-radiation solution of the
cavity's integral equation (Sparrow, Albers & Eckert 1962; Sparrow & Cess ch. 7), computed by
tests/validation/cavity_radiosity.py with exact exchange factors; its discretisation error is
below 1e-5 (200 vs 400 wall bands). Model tolerance: 0.2 % for the 256-facet wall (its area and
shape differ from the circle by < 0.01 %; 0.2 % also covers the 0.5 deg emissivity table).
The references (0.8083 at eps 0.5, L/R 2; 0.9307 at eps 0.75, L/R 4) are not a printed table:
none was reachable offline. Gouffe's approximate formula (Rev. Opt. 24, 1 (1945)), as usually
quoted, gives 0.821 and 0.977: 1.6 % and 5 % above, the known weakness of a sphere-based
approximation for deep cylinders; it is not used as a reference."""
import warnings

import numpy as np
import pytest

from straylight.scene import load_scene
from straylight.thermal.model import thermal_scene
from straylight.thermal.planck import band_radiance_w_m2_sr
from straylight.thermal.run import thermal
from tests.validation.cavity_radiosity import effective_emissivity
from tests.validation.thermal_scenes import part, plane, write_scene, write_tube_inward


@pytest.mark.parametrize("eps_wall,depth_over_radius", [(0.5, 2.0), pytest.param(0.75, 4.0, marks=pytest.mark.slow)])
def test_cylindrical_cavity_effective_emissivity(tmp_path, eps_wall, depth_over_radius):
    R, L = 10.0, 10.0 * depth_over_radius
    wall = write_tube_inward(tmp_path, R, L)
    text = f"""
[material.wallpaint]
components = [{{type = "lambertian", rd = {1 - eps_wall}}}]
"""
    text += part("wall", "wallpaint", 500.0, mesh=wall)
    text += part("bottom", "wallpaint", 500.0, surface=plane((0, 0, 0), (0, 0, 1), R))
    text += part("opening", role="detector", surface=plane((0, 0, L), (0, 0, -1), R))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rs = load_scene(write_scene(tmp_path, text), sources=False)
    res = thermal(thermal_scene(rs.scene, rs.materials), (3, 5), n_rays=12_000, seed=11)
    d = res.detectors["opening"]
    pib = np.pi * band_radiance_w_m2_sr(3, 5, 500.0)
    eps_a, err = d.irradiance_w_m2 / pib, d.stderr_w / (d.area_mm2 * 1e-6) / pib
    ref = effective_emissivity(eps_wall, R, L)
    assert ref == pytest.approx(effective_emissivity(eps_wall, R, L, 400, 80), abs=1e-5)
    assert 0 < err < 0.005
    assert abs(eps_a - ref) <= 3 * err + 2e-3 * ref, (eps_a, err, ref)
