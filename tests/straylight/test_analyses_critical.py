"""Critical / illuminated objects on a scene built so the answer is known, and the view factor."""
import math

import numpy as np
import pytest

from geometry.mesh import Part, Scene
from materials import Lambertian
from straylight.analyses.types import Beam, Setup
from straylight.analyses.critical import LambertianPart, critical_objects


def rect(center, u, v):
    """Two triangles spanning center +- u +- v; normal along u x v."""
    c, u, v = (np.asarray(x, float) for x in (center, u, v))
    verts = np.array([c - u - v, c + u - v, c + u + v, c - u + v])
    return verts, np.array([[0, 1, 2], [0, 2, 3]])


def part(name, center, u, v, role="surface"):
    verts, faces = rect(center, u, v)
    return Part(name, verts, faces, material=None if role == "detector" else "grey", role=role)


@pytest.fixture(scope="module")
def known_scene():
    """x-z plane picture (plates are 80 mm deep in y):

    - detector: 10 x 10 mm at z = 0, sensitive side +z; it sees only z > 0
    - beam: collimated along +x, a disk of radius 30 (z in -30..30) starting at x = -100
    - lit_and_seen: wall x = 50, z 0..40, facing -x: in the beam and above the detector
    - lit_hidden: wall x = 60, z -30..-1, facing -x: in the beam, below the detector's plane
    - seen_dark: ceiling z = 80, x -20..20, facing -z: above the detector, out of the beam
    Expected: critical {lit_and_seen, seen_dark}, illuminated {lit_and_seen, lit_hidden},
    both = [lit_and_seen].
    """
    parts = (
        part("detector", (0, 0, 0), (5, 0, 0), (0, 5, 0), role="detector"),
        part("lit_and_seen", (50, 0, 20), (0, 0, 20), (0, 40, 0)),
        part("lit_hidden", (60, 0, -15.5), (0, 0, 14.5), (0, 40, 0)),
        part("seen_dark", (0, 0, 80), (0, 40, 0), (20, 0, 0)),
    )
    scene = Scene(parts)
    beam = Beam(center_mm=(-100, 0, 0), axis=(1, 0, 0), radius_mm=30.0)
    return Setup(scene, {"grey": Lambertian(rd=0.2)}, beam, None, "detector")


def test_critical_illuminated_and_both_on_known_scene(known_scene):
    rep = critical_objects(known_scene, 0.0, n_rays=20_000, seed=4)
    assert set(rep.critical) == {"lit_and_seen", "seen_dark"}
    assert set(rep.illuminated) == {"lit_and_seen", "lit_hidden"}
    assert [r.part for r in rep.ranking] == ["lit_and_seen"]
    rows = {r.part: r for r in rep.rows}
    # beam fractions: the wall z 0..40 takes the upper half of the disk, the other the z -30..-1 part
    # (segment of a disk of radius 30 below z = -1): area / (pi 30^2), analytic circle segment
    seg = 30**2 * math.acos(1 / 30) - 1 * math.sqrt(30**2 - 1)
    expected_hidden = seg / (math.pi * 30**2)
    r = rows["lit_hidden"]
    assert abs(r.illuminated - expected_hidden) < 4 * r.illuminated_stderr  # binomial error of the run; 4 sigma
    r = rows["lit_and_seen"]
    assert abs(r.illuminated - 0.5) < 4 * r.illuminated_stderr


def test_view_factor_of_parallel_plates_matches_analytic(known_scene):
    """The reverse trace's first-hit fraction is the view factor F(detector -> part).

    Detector 10 x 10 mm, centred under the 40 x 80 mm ceiling 80 mm above it (nothing in
    between). Expected: the differential-element-to-parallel-rectangle factor (Howell, "A
    Catalog of Radiation Heat Transfer Configuration Factors"), summed over the four
    rectangles that meet above the element, averaged over the detector by scipy dblquad."""
    from scipy import integrate

    rep = critical_objects(known_scene, 0.0, n_rays=40_000, seed=9)
    r = {x.part: x for x in rep.rows}["seen_dark"]

    def point_to_rect(x, y):
        """F(d A at (x, y, 0) facing +z -> rectangle |X| < 20, |Y| < 40 at height 80): sum of
        four corner rectangles, each (1 / 2 pi) [A/sqrt(1+A^2) atan(B/sqrt(1+A^2)) + B/sqrt(1+B^2) atan(A/sqrt(1+B^2))]."""
        h = 80.0
        total = 0.0
        for a in (20 - x, 20 + x):
            for b in (40 - y, 40 + y):
                A, B = a / h, b / h
                total += (A / math.sqrt(1 + A * A) * math.atan(B / math.sqrt(1 + A * A))
                          + B / math.sqrt(1 + B * B) * math.atan(A / math.sqrt(1 + B * B))) / (2 * math.pi)
        return total

    expected = integrate.dblquad(lambda y, x: point_to_rect(x, y), -5, 5, -5, 5)[0] / 100.0
    assert r.view_factor > 0
    assert abs(r.view_factor - expected) < 4 * r.view_factor_stderr, (r.view_factor, expected, r.view_factor_stderr)


def test_lambertian_part_emits_cosine_from_its_area():
    verts, faces = rect((0, 0, 0), (1, 0, 0), (0, 2, 0))
    src = LambertianPart(verts[faces], both_sides=False)
    rng = np.random.default_rng(0)
    o, d = src.emit(rng.random((200_000, 4)))
    assert np.all(np.abs(o[:, 0]) <= 1) and np.all(np.abs(o[:, 1]) <= 2)
    # uniform over the area: mean of x^2 = 1/3
    assert abs(np.mean(o[:, 0] ** 2) - 1 / 3) < 0.01
    # cosine-weighted: E[cos] = 2/3, all into +z
    assert np.all(d[:, 2] > 0)
    assert abs(d[:, 2].mean() - 2 / 3) < 0.005
