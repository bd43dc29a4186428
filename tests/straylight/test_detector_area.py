"""Detector area as a user means it (CONTRACTS §4.5): a closed thin-solid detector from CAD reads the
same PST as the one-sided disk of its front face.

The scene is the reference tube of shared/BENCHMARK.md (Lambertian 5 % walls and vanes). The two
detectors are built from one polygon (a 0.5 mm thick 256-gon disk of radius 35 mm, top at z = 0):
the closed solid (front, back, rim) and its front face alone. Their PSTs are compared within
3 combined standard errors of the two runs; before the sensitive-area rule the solid divided by all
its faces (2.03x the front) and read half.
"""
import math

import numpy as np
import pytest
import trimesh

from straylight.detectors import sensitive_area


@pytest.fixture(scope="module")
def disks():
    cyl = trimesh.creation.cylinder(radius=35.0, height=0.5, sections=256)
    cyl.apply_translation([0.0, 0.0, -0.25])
    v, f = np.asarray(cyl.vertices), np.asarray(cyl.faces)
    front = f[np.asarray(cyl.face_normals)[:, 2] > 0.99]
    return v, f, front


def _with_detector(base, vertices, faces):
    from geometry.mesh import Part, Scene
    from straylight.analyses.types import Setup

    parts = tuple(p for p in base.scene.parts if p.role != "detector")
    parts += (Part("detector", vertices, faces, None, "detector", {}),)
    return Setup(Scene(parts), base.materials, base.beam, base.entrance, "detector", "", base.params)


def test_sensitive_area_rules(disks):
    v, f, front = disks
    polygon = 0.5 * 256 * 35.0**2 * math.sin(2 * math.pi / 256)  # area of the regular 256-gon
    solid = sensitive_area(v, f, toward_mm=(0, 0, 300))
    disk = sensitive_area(v, front, toward_mm=(0, 0, 300))
    assert solid.closed and not disk.closed
    assert solid.area_mm2 == pytest.approx(polygon, rel=1e-12)
    assert disk.area_mm2 == pytest.approx(polygon, rel=1e-12)
    assert solid.total_area_mm2 == pytest.approx(2 * polygon + 256 * 2 * 35 * math.sin(math.pi / 256) * 0.5, rel=1e-9)
    # the front is the side toward the instrument: seen from below, the other face counts
    assert sensitive_area(v, f, toward_mm=(0, 0, -300)).area_mm2 == pytest.approx(polygon, rel=1e-12)


def test_thin_solid_detector_reads_the_pst_of_its_front_disk(disks):
    from materials import load_material
    from straylight.analyses.builtin import tube_setup
    from straylight.analyses.pst import pst_sweep

    lam = load_material({"components": [{"type": "lambertian", "rd": 0.05}]}, name="benchmark_lambertian_5pc")
    base = tube_setup(material=lam)
    v, f, front = disks
    runs = [pst_sweep(_with_detector(base, v, faces), np.radians([0.0, 20.0]), n_rays=20_000, seed=1)
            for faces in (f, front)]
    solid, disk = runs
    assert solid.detector_area_mm2 == pytest.approx(disk.detector_area_mm2, rel=1e-12)
    assert "closed part" in solid.detector_area_rule and "open part" in disk.detector_area_rule
    for i in range(2):
        sigma = math.hypot(solid.pst_stderr[i], disk.pst_stderr[i])
        assert sigma > 0
        assert abs(solid.pst[i] - disk.pst[i]) < 3 * sigma, (i, solid.pst[i], disk.pst[i], sigma)
    assert disk.pst[0] > 0.9  # on axis the detector is fully lit: PST ~ 1
    assert 0 < disk.pst[1] < 1e-3
