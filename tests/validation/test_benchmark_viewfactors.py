"""The tracer against the analytic references of PHYSICS.md §5 (lengths scaled to mm).

Each Monte Carlo estimate must lie within 3.5 of its own standard errors of the formula (fixed
seeds; the ray counts are chosen so that one standard error is ~0.5 % of the value). Polygon
approximations of circles are circumscribed or corrected so that their geometric error is
below 1e-4 relative, far under the statistical tolerance.
"""
import math
import sys
from pathlib import Path

import numpy as np
from dataclasses import dataclass

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "straylight"))
from engine_helpers import (  # noqa: E402
    StandInLambertian, cylinder_wall_part, disk_part, icosphere_ports_scene,
)

from geometry.mesh import Scene  # noqa: E402
from straylight.sources import CollimatedDisk, LambertianDisk, orthonormal_basis  # noqa: E402
from straylight.trace import TraceOptions, trace  # noqa: E402

SCALE_MM = 100.0
K_SIGMA = 3.5


def coaxial_disks(r1, r2, h):
    """View factor from disk r1 to a parallel coaxial disk r2 at distance h (PHYSICS §5)."""
    R1, R2 = r1 / h, r2 / h
    X = 1 + (1 + R2 ** 2) / R1 ** 2
    return (X - math.sqrt(X * X - 4 * (R2 / R1) ** 2)) / 2


def _check(tally, expected):
    assert tally.power_w > 0
    assert abs(tally.power_w - expected) < K_SIGMA * tally.stderr_w, (tally, expected)


def _balanced(res):
    total = (sum(t.power_w for t in res.detectors.values()) + sum(t.power_w for t in res.absorbed.values())
             + res.escaped.power_w)
    assert abs(total - res.emitted_w) <= 1e-9 * res.emitted_w


def test_coaxial_disk_to_disk_view_factor():
    r1, r2, h = 0.1 * SCALE_MM, 0.2 * SCALE_MM, 0.5 * SCALE_MM
    assert abs(coaxial_disks(0.1, 0.2, 0.5) - 0.1339) < 5e-5  # PHYSICS.md golden value
    det = disk_part("disk2", h, r2, 2048)
    res = trace(Scene((det,)), LambertianDisk([0, 0, 0], [0, 0, 1], r1), 100_000, seed=7)
    # the inscribed 2048-gon's area is 1.6e-6 below the circle's: negligible here
    _check(res.detectors["disk2"], coaxial_disks(r1, r2, h))
    _balanced(res)


def test_cylinder_base_to_wall():
    r, h = 1.0 * SCALE_MM, 2.0 * SCALE_MM
    f_end = coaxial_disks(r, r, h)
    expected = 1 - f_end
    assert abs(expected - 0.8284) < 5e-5
    wall = cylinder_wall_part("wall", r, 0.0, h, 1024)  # circumscribes the emitting disk
    res = trace(Scene((wall,)), LambertianDisk([0, 0, 0], [0, 0, 1], r), 40_000, seed=3)
    _check(res.detectors["wall"], expected)
    _balanced(res)


@dataclass(frozen=True)
class LambertianCylinderWall:
    """Test source: uniform Lambertian emission from the inside of a cylinder wall, inward."""

    radius_mm: float
    z0_mm: float
    z1_mm: float
    power_w: float = 1.0

    def emit(self, u):
        phi = 2 * np.pi * u[:, 0]
        z = self.z0_mm + (self.z1_mm - self.z0_mm) * u[:, 1]
        o = np.stack([self.radius_mm * np.cos(phi), self.radius_mm * np.sin(phi), z], axis=1)
        n = -o.copy()
        n[:, 2] = 0
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        t, b = orthonormal_basis(n)
        rr = np.sqrt(u[:, 2])
        a = 2 * np.pi * u[:, 3]
        c = np.sqrt(1 - rr * rr)
        d = (rr * np.cos(a))[:, None] * t + (rr * np.sin(a))[:, None] * b + c[:, None] * n
        return o, d


def test_cylinder_wall_to_base():
    r, h = 1.0 * SCALE_MM, 0.5 * SCALE_MM
    expected = (1 - coaxial_disks(r, r, h)) * math.pi * r ** 2 / (2 * math.pi * r * h)
    assert abs(expected - 0.3904) < 5e-5
    n_seg = 1024
    wall = cylinder_wall_part("wall", r * (1 + 1e-6), -1.0, h + 1.0, n_seg, role="absorber")
    base = disk_part("base", 0.0, r, n_seg, circumscribe=True)
    src = LambertianCylinderWall(r, 0.0, h)
    res = trace(Scene((wall, base)), src, 40_000, seed=5)
    _check(res.detectors["base"], expected)
    _balanced(res)


def test_integrating_sphere_throughput():
    """Goebel (1967): throughput = rho f_d / (1 - rho (1 - f)), with the mesh's actual port fractions.

    rho = 0.98, entrance port ~0.01 (a hole: light leaving through it escapes), detector port ~0.005;
    the beam enters through the entrance and first strikes the wall opposite.
    """
    R = 100.0
    scene, frac = icosphere_ports_scene(
        R, {"entrance": ([0, 0, 1], 0.01, None), "port": ([1, 0, 0], 0.005, "detector")}, subdivisions=4)
    rho = 0.98
    f_d = frac["port"]
    f = frac["entrance"] + f_d
    assert abs(frac["entrance"] - 0.01) < 0.002 and abs(f_d - 0.005) < 0.001
    expected = rho * f_d / (1 - rho * (1 - f))
    assert abs(0.98 * 0.005 / (1 - 0.98 * 0.985) - 0.14121) < 1e-5  # PHYSICS.md golden value
    src = CollimatedDisk([0, 0, 0.97 * R], [0, 0, -1], [0, 0, -1], 2.0)
    res = trace(scene, src, 6000, seed=2, materials={"wall": StandInLambertian(rho)},
                options=TraceOptions(batch_rays=6000))
    _check(res.detectors["port"], expected)
    assert res.detectors["port"].stderr_w < 0.01 * expected  # precise enough to mean something
    _balanced(res)
