"""An imported anisotropic BSDF (ua-loft IMX455, Zemax Asymmetrical4D) on a plate turned about its normal by
0, 30 and 90 deg: the power a small off-plane detector receives changes as the file says.

Golden values: the file's own BRDF at the sample rotation each turn puts in the plane of incidence
(docs/bsdf-files.md: a part turned by psi about its normal, lit in the scene's x-z plane from -x, sees
the file's SampleRotation -psi - 90 deg), times cos theta_r and the detector's solid angle.
"""
from __future__ import annotations

import gzip
import math
from pathlib import Path

import numpy as np
import pytest

from materials.base import directions_from_angles
from materials.bsdf_files import import_file
from materials.bsdf_table import rotated
from materials.material import save_material

DATA = Path(__file__).resolve().parents[1] / "data" / "bsdf"
THETA_I = 30.0
THETA_R, PHI_R = 35.0, 60.0  # detector direction (world = plate frame: the plate's normal is +z)
DIST_MM, DET_R_MM = 200.0, 8.0


def _stl(path):
    v = [(-15, -15, 0), (15, -15, 0), (15, 15, 0), (-15, 15, 0)]
    tris = [(v[0], v[1], v[2]), (v[0], v[2], v[3])]
    lines = ["solid plate"]
    for t in tris:
        lines += ["facet normal 0 0 1", "outer loop", *[f"vertex {a} {b} {c}" for a, b, c in t], "endloop", "endfacet"]
    path.write_text("\n".join(lines + ["endsolid plate"]) + "\n")


def _scene(tmp_path, turn_deg):
    th, ph = math.radians(THETA_R), math.radians(PHI_R)
    wo = np.array([math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)])
    c = DIST_MM * wo
    ti = math.radians(THETA_I)
    d = [math.sin(ti), 0.0, -math.cos(ti)]
    src = [-150.0 * math.sin(ti), 0.0, 150.0 * math.cos(ti)]
    text = f'''
[[part]]
name = "plate"
mesh = "plate.stl"
material = "imx.json"
rotate_deg = {{axis = [0.0, 0.0, 1.0], angle = {turn_deg}}}

[[part]]
name = "det"
surface = {{type = "plane", vertex_mm = [{c[0]}, {c[1]}, {c[2]}], axis = [{-wo[0]}, {-wo[1]}, {-wo[2]}], outer_radius_mm = {DET_R_MM}}}
role = "detector"

[[source]]
type = "collimated_disk"
center_mm = {src}
normal = {d}
direction = {d}
radius_mm = 4.0
power_w = 1.0
'''
    path = tmp_path / f"turn{turn_deg}.toml"
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("aniso")
    src = tmp / "IMX455.bsdf"
    src.write_bytes(gzip.decompress((DATA / "IMX455.bsdf.gz").read_bytes()))
    material, _ = import_file(src)
    save_material(tmp / "imx.json", material, check_energy=False)
    _stl(tmp / "plate.stl")
    return tmp, material


def test_turned_plate_changes_as_the_file_says(setup):
    from straylight.scene import load_scene

    tmp, material = setup
    # the detector disk as seen from the plate's centre: f cos d Omega summed over a polar grid of it
    _, wo_c = directions_from_angles(0.0, math.radians(THETA_R), math.radians(PHI_R))
    n = -wo_c[0]
    t = np.cross(n, [0.0, 0.0, 1.0])
    t /= np.linalg.norm(t)
    b = np.cross(n, t)
    r = (np.arange(24) + 0.5) / 24 * DET_R_MM
    a = (np.arange(48) + 0.5) / 48 * 2 * math.pi
    rr, aa = np.meshgrid(r, a, indexing="ij")
    pts = DIST_MM * wo_c[0] + (rr * np.cos(aa))[..., None] * t + (rr * np.sin(aa))[..., None] * b
    dist = np.linalg.norm(pts, axis=-1)
    wo = (pts / dist[..., None]).reshape(-1, 3)
    d_omega = (rr * (DET_R_MM / 24) * (2 * math.pi / 48) * np.abs(wo.reshape(rr.shape + (3,)) @ n) / dist**2).ravel()
    ti = math.radians(THETA_I)
    wi = np.tile([-math.sin(ti), 0.0, math.cos(ti)], (len(wo), 1))
    got, want = {}, {}
    for turn in (0.0, 30.0, 90.0):
        f = rotated(material, -turn - 90.0).brdf(wi, wo)
        want[turn] = float(np.sum(f * wo[:, 2] * d_omega))
        rs = load_scene(_scene(tmp, turn))
        res = rs.trace(20_000, seed=1)
        got[turn] = res.detectors["det"].power_w
    # the file's values differ by rotation at this direction (otherwise the test could not fail)
    assert max(want.values()) / min(want.values()) > 1.3, want
    for turn in want:
        assert got[turn] == pytest.approx(want[turn], rel=0.06), (turn, got, want)
