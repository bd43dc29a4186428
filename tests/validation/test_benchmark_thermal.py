"""Thermal self-emission against closed forms (CONTRACTS §7). Tolerances: the run's own
standard error (fixed seed) times 3, plus the stated model tolerance."""
import warnings

import numpy as np
import pytest

from straylight.scene import load_scene
from straylight.thermal.model import thermal_scene
from straylight.thermal.planck import band_radiance_w_m2_sr
from straylight.thermal.run import thermal
from tests.validation.thermal_scenes import (
    part,
    plane,
    view_factor_coaxial_disks,
    write_box,
    write_scene,
)


def _ts(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rs = load_scene(path, sources=False)
    return thermal_scene(rs.scene, rs.materials)


def _enclosure(tmp_path, t_k=300.0, det_r=5.0):
    meshes = write_box(tmp_path)
    mats = {"floor": "black", "ceiling": "mirror", "wx0": "glossy", "wx1": "glossy", "wy0": "mirror", "wy1": "grey"}
    text = "".join(part(n, mats[n], t_k, mesh=m) for n, m in meshes.items())
    text += part("det", role="detector", temperature_k=t_k, surface=plane((50, 50, 0.5), (0, 0, 1), det_r))
    return write_scene(tmp_path, text)


@pytest.mark.parametrize("method,det_r,rays", [("reverse", 5.0, 12_000), ("forward", 30.0, 24_000)])
def test_isothermal_enclosure_irradiance_is_pi_b(tmp_path, method, det_r, rays):
    """Closed box at 300 K, walls black / grey / glossy (Lambertian + K-correlation, 5 traced
    sub-bands) / specular mirror, detector at 300 K inside: E = pi B_band(T) whatever the BRDFs.
    Model tolerance 0.1 %: emissivity tables (0.5 deg grid, 2.5 deg albedo table of the glossy lobe).
    The forward estimator gets a larger detector (its mirror paths reach it only by chance) and more
    rays (the engine's trace has no next-event estimation at the emission point)."""
    ts = _ts(_enclosure(tmp_path, det_r=det_r))
    res = thermal(ts, (8, 12), n_rays=rays, seed=3, method=method)
    d = res.detectors["det"]
    expect = np.pi * band_radiance_w_m2_sr(8, 12, 300.0)
    err = d.stderr_w / (d.area_mm2 * 1e-6)
    assert d.power_w > 0 and err < 0.03 * expect
    assert abs(d.irradiance_w_m2 - expect) <= 3 * err + 1e-3 * expect
    assert sum(t.power_w for t in d.by_part.values()) == pytest.approx(d.power_w, rel=1e-9)
    assert len(res.sub_bands) == 5  # the glossy lobe depends on wavelength


def test_isothermal_mirror_box_with_a_floating_detector(tmp_path):
    """Five mirror walls (r = 0.9) and one glossy, all at 300 K, a one-sided detector disk (r = 10 mm)
    floating mid-box: light reaches its back too, which absorbs and therefore emits (Kirchhoff on
    every side that can be seen). E = pi B_band(T); without the back's emission it reads 1.5 % low
    (13 sigma at these rays)."""
    meshes = write_box(tmp_path)
    mats = {"floor": "mirror", "ceiling": "mirror", "wx0": "glossy", "wx1": "mirror", "wy0": "mirror", "wy1": "mirror"}
    text = "".join(part(n, mats[n], 300.0, mesh=m) for n, m in meshes.items())
    text += part("det", role="detector", temperature_k=300.0, surface=plane((50, 50, 50), (0, 0, 1), 10.0))
    d = thermal(_ts(write_scene(tmp_path, text)), (8, 12), n_rays=6000, seed=3).detectors["det"]
    expect = np.pi * band_radiance_w_m2_sr(8, 12, 300.0)
    err = d.stderr_w / (d.area_mm2 * 1e-6)
    assert 0 < err < 0.002 * expect
    assert abs(d.irradiance_w_m2 - expect) <= 3 * err + 1e-3 * expect


@pytest.mark.parametrize("method", ["reverse", "forward"])
def test_narcissus_in_a_flat_mirror_is_the_view_factor_to_its_image(tmp_path, method):
    """A warm detector disk (r = 10 mm, 300 K) under a flat mirror (r = 0.9, 0 K) at h = 20 mm:
    it receives its own emission R pi B A F(r, r, 2h), F the coaxial-disk view factor to its image
    (PHYSICS §5). Exact for a flat mirror; model tolerance 0."""
    text = part("det", role="detector", temperature_k=300.0, surface=plane((0, 0, 0), (0, 0, 1), 10.0))
    text += part("mirror", "mirror", 0.0, surface=plane((0, 0, 20), (0, 0, -1), 30.0))
    ts = _ts(write_scene(tmp_path, text))
    res = thermal(ts, (8, 12), n_rays=20_000, seed=5, method=method)
    d = res.detectors["det"]
    area_m2 = np.pi * 10.0 ** 2 * 1e-6
    expect = 0.9 * np.pi * band_radiance_w_m2_sr(8, 12, 300.0) * area_m2 * view_factor_coaxial_disks(10, 10, 40)
    assert d.power_w > 0
    assert abs(d.power_w - expect) <= 3 * d.stderr_w, (d.power_w, d.stderr_w, expect)
    assert list(d.by_part) == ["det"]


def test_cold_detector_under_a_warm_disk(tmp_path):
    """A black disk (r = 20 mm, 300 K, front toward the detector) at 30 mm over a 77 K detector
    (r = 5 mm): P = pi B(300) A_disk F(disk -> det) + 0 (the detector sees nothing of itself)."""
    text = part("det", role="detector", temperature_k=77.0, surface=plane((0, 0, 0), (0, 0, 1), 5.0))
    text += part("hot", role="absorber", temperature_k=300.0, surface=plane((0, 0, 30), (0, 0, -1), 20.0))
    ts = _ts(write_scene(tmp_path, text))
    res = thermal(ts, (8, 12), n_rays=8_000, seed=2)
    d = res.detectors["det"]
    expect = np.pi * band_radiance_w_m2_sr(8, 12, 300.0) * np.pi * 20 ** 2 * 1e-6 * view_factor_coaxial_disks(20, 5, 30)
    assert abs(d.power_w - expect) <= 3 * d.stderr_w + 1e-12
    assert d.by_part["det"].power_w == 0.0


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_open_detector_sheet_faces_the_scene_whatever_its_winding(tmp_path, sign):
    """An STL disk detector (256-gon, r = 5 mm) under a warm black disk: the same power whichever way
    its triangles are wound (its front is turned toward the scene), as the analytic-plane check above."""
    from tests.validation.thermal_scenes import write_disk

    det = write_disk(tmp_path, "det", 5.0, 0.0, normal_sign=sign)
    text = part("det", role="detector", temperature_k=77.0, mesh=det)
    text += part("hot", role="absorber", temperature_k=300.0, surface=plane((0, 0, 30), (0, 0, -1), 20.0))
    res = thermal(_ts(write_scene(tmp_path, text)), (8, 12), n_rays=8_000, seed=2)
    d = res.detectors["det"]
    area = 0.5 * 256 * 25.0 * np.sin(2 * np.pi / 256)  # the polygon's area, mm^2
    expect = np.pi * band_radiance_w_m2_sr(8, 12, 300.0) * np.pi * 20 ** 2 * 1e-6 * view_factor_coaxial_disks(20, 5, 30)
    assert d.area_mm2 == pytest.approx(area, rel=1e-6)  # STL vertices are float32
    assert abs(d.power_w / area - expect / (np.pi * 25)) * area <= 3 * d.stderr_w + 1e-3 * expect


def test_cold_detector_in_a_warm_mirror(tmp_path):
    """A 77 K detector (r = 10 mm) under a 300 K flat mirror (specular r = 0.9, so eps = 0.1, r = 30 mm)
    at h = 20 mm, 3-5 um: the mirror's own emission eps pi B(300) A_m F(m -> d) and the narcissus
    R pi B(77) A_d F(d -> image at 2h), each by its part (coaxial-disk view factors, PHYSICS §5)."""
    text = part("det", role="detector", temperature_k=77.0, surface=plane((0, 0, 0), (0, 0, 1), 10.0))
    text += part("mirror", "mirror", 300.0, surface=plane((0, 0, 20), (0, 0, -1), 30.0))
    res = thermal(_ts(write_scene(tmp_path, text)), (3, 5), n_rays=20_000, seed=8)
    d = res.detectors["det"]
    own = 0.1 * np.pi * band_radiance_w_m2_sr(3, 5, 300.0) * np.pi * 900e-6 * view_factor_coaxial_disks(30, 10, 20)
    narc = 0.9 * np.pi * band_radiance_w_m2_sr(3, 5, 77.0) * np.pi * 100e-6 * view_factor_coaxial_disks(10, 10, 40)
    m, n = d.by_part["mirror"], d.by_part["det"]
    assert m.power_w > 0 and n.power_w > 0
    assert abs(m.power_w - own) <= 3 * m.stderr_w
    assert abs(n.power_w - narc) <= 3 * n.stderr_w
