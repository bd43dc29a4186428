"""Invariants of the tracer: the Monte Carlo error falls as 1/sqrt(N); a rigid motion of the whole
scene (geometry and source together) leaves the answer unchanged within errors."""
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "straylight"))
from engine_helpers import StandInLambertian, disk_part  # noqa: E402

from geometry.mesh import Part, Scene  # noqa: E402
from straylight.sources import CollimatedDisk  # noqa: E402
from straylight.trace import trace  # noqa: E402

MATS = {"grey": StandInLambertian(0.5)}


def _scene(rot=np.eye(3), shift=np.zeros(3)):
    floor = disk_part("floor", 0.0, 40.0, 128, role="surface", material="grey")
    det = disk_part("det", 30.0, 8.0, 64, role="detector")
    parts = []
    for p, offset in ((floor, 0.0), (det, -25.0)):
        v = (p.vertices_mm + [offset, 0, 0]) @ rot.T + shift
        parts.append(Part(p.name, v, p.faces, material=p.material, role=p.role))
    src = CollimatedDisk(np.array([0, 0, 50.0]) @ rot.T + shift, np.array([0, 0, -1.0]) @ rot.T,
                         np.array([0.3, 0, -1.0]) @ rot.T, 15.0)
    return Scene(tuple(parts)), src


def test_standard_error_falls_as_one_over_sqrt_n():
    scene, src = _scene()
    small = trace(scene, src, 5000, seed=1, materials=MATS).detectors["det"]
    large = trace(scene, src, 80000, seed=2, materials=MATS).detectors["det"]
    assert small.power_w > 0 and large.power_w > 0
    # 16x the rays: 4x smaller error. The error estimates themselves scatter by ~1/sqrt(2N) of
    # the heavier-tailed per-ray contributions; 25 % is ample at these N.
    assert abs(small.stderr_w / large.stderr_w / 4.0 - 1.0) < 0.25
    assert abs(small.power_w - large.power_w) < 4 * math.hypot(small.stderr_w, large.stderr_w)


def test_rigid_motion_leaves_the_answer_unchanged():
    a = 0.7
    rot = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    rot = rot @ np.array([[math.cos(1.1), -math.sin(1.1), 0], [math.sin(1.1), math.cos(1.1), 0], [0, 0, 1]])
    base = trace(*_scene(), 30000, seed=3, materials=MATS)
    moved = trace(*_scene(rot, np.array([120.0, -340.0, 75.0])), 30000, seed=4, materials=MATS)
    x, y = base.detectors["det"], moved.detectors["det"]
    assert x.power_w > 0
    assert abs(x.power_w - y.power_w) < 4 * math.hypot(x.stderr_w, y.stderr_w)
    # (every ray hits the floor once, so its absorption may be exact: allow round-off)
    assert abs(base.absorbed["floor"].power_w - moved.absorbed["floor"].power_w) <= 4 * math.hypot(
        base.absorbed["floor"].stderr_w, moved.absorbed["floor"].stderr_w) + 1e-12
