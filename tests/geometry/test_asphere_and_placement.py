"""CONTRACTS §6.1 ``asphere``, ``offset_mm`` and ``tilt_deg``, checked against references written here.

- The sag is the printed formula evaluated term by term in plain Python (Zemax "Even Asphere" /
  CODE V ``ASP``: conic sag + A4 rho^4 + A6 rho^6 + ...).
- Hits: the root of ``sag(rho(t)) - z(t)`` found by bisection along each ray (no derivative, no mesh),
  against the engine's compiled Newton kernel started from the mesh hit.
- Normals: a central finite difference of the sag, ``(-h'(rho) cos phi, -h'(rho) sin phi, 1)``.
- Placement: the rotation matrix written out from its definition (x, then y, then z, about the
  vertex; then the offset), and an off-axis paraboloid placed that way still focusing to 1e-6 mm.
"""
import math

import numpy as np
import pytest

from geometry.analytic import analytic_part, surface_from_dict
from geometry.mesh import GeometryError
from materials.smooth import reflect
from straylight.intersect import EmbreeIntersector

ASPHERE = {"type": "asphere", "vertex_mm": [0.0, 0.0, 0.0], "axis": [0.0, 0.0, 1.0], "radius_mm": 40.0,
           "conic": -0.6, "coefficients": [2.0e-6, -3.0e-9, 1.5e-12], "outer_radius_mm": 20.0}


def _sag_reference(rho, radius, k, coefs):
    c = 1.0 / radius
    h = c * rho * rho / (1.0 + math.sqrt(1.0 - (1.0 + k) * c * c * rho * rho))
    for i, a in enumerate(coefs):
        h += a * rho ** (2 * i + 4)
    return h


def test_asphere_sag_is_the_printed_formula():
    s = surface_from_dict(ASPHERE)
    for rho in (0.0, 3.0, 11.0, 19.9):
        ref = _sag_reference(rho, 40.0, -0.6, ASPHERE["coefficients"])
        assert s.sag(np.array([rho]))[0] == pytest.approx(ref, rel=1e-13, abs=1e-15)
    # the polynomial matters: at the edge it moves the surface by more than a micron
    assert abs(s.sag(np.array([19.9]))[0] - _sag_reference(19.9, 40.0, -0.6, [])) > 1e-3


def _bisect_hits(o, d, sag):
    """Root of sag(rho) - z along each ray between z = +5 and z = -15 (the asphere lies in between)."""
    t_out = np.empty(len(o))
    for i in range(len(o)):
        def g(t):
            p = o[i] + t * d[i]
            return sag(math.hypot(p[0], p[1])) - p[2]
        lo, hi = (o[i, 2] - 15.0) / -d[i, 2], (o[i, 2] + 5.0) / -d[i, 2]
        glo = g(lo)
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            gm = g(mid)
            if (gm > 0) == (glo > 0):
                lo, glo = mid, gm
            else:
                hi = mid
        t_out[i] = 0.5 * (lo + hi)
    return t_out


def check_hits_and_normals(surface: dict, sag, tolerance_mm: float, seed: int = 3, r_min: float = 0.0,
                           eps: float = 1e-5):
    """Hits of 300 rays from z = 30 on ``surface`` (meshed at ``tolerance_mm``, refined by the compiled kernel)
    against the bisection root of ``sag(rho) - z``, normals against a central difference of ``sag``, and the
    numpy path (implicit / gradient) against the kernel."""
    s = surface_from_dict(surface)
    part = analytic_part("asph", s, "al", tolerance_mm=tolerance_mm)
    isect = EmbreeIntersector(part.vertices_mm[part.faces])
    rng = np.random.default_rng(seed)
    n = 300
    r = r_min + (19.0 - r_min) * np.sqrt(rng.uniform(0, 1, n))
    phi = rng.uniform(0, 2 * np.pi, n)
    o = np.column_stack([r * np.cos(phi), r * np.sin(phi), np.full(n, 30.0)])
    d = np.column_stack([rng.normal(0, 0.05, n), rng.normal(0, 0.05, n), -np.ones(n)])
    d /= np.linalg.norm(d, axis=1)[:, None]
    tri, t0 = isect.intersect(o, d)
    keep = tri >= 0
    assert keep.mean() > 0.95
    o, d, t0 = o[keep], d[keep], t0[keep]
    t, nrm, ok = s.refine_hits(o, d, t0)
    assert np.all(ok)
    np.testing.assert_allclose(t, _bisect_hits(o, d, sag), atol=1e-9)
    p = o + t[:, None] * d
    rho = np.hypot(p[:, 0], p[:, 1])
    slope = np.array([(sag(x + eps) - sag(x - eps)) / (2 * eps) for x in rho])
    cphi, sphi = p[:, 0] / rho, p[:, 1] / rho
    ref = np.column_stack([-slope * cphi, -slope * sphi, np.ones(len(p))])
    ref /= np.linalg.norm(ref, axis=1)[:, None]
    np.testing.assert_allclose(nrm, ref, atol=1e-8)
    # the numpy path (implicit / gradient) agrees with the compiled kernel
    np.testing.assert_allclose(s.normals(p), nrm, atol=1e-12)
    t_np, ok_np = s.refine(o, d, t0)
    assert np.all(ok_np)
    np.testing.assert_allclose(t_np, t, atol=1e-9)


@pytest.mark.parametrize("tolerance_mm", [0.2, 0.005])
def test_asphere_hits_and_normals_against_bisection_and_finite_differences(tolerance_mm):
    check_hits_and_normals(ASPHERE, lambda rho: _sag_reference(rho, 40.0, -0.6, ASPHERE["coefficients"]), tolerance_mm)


def test_asphere_with_no_coefficients_is_the_conic():
    conic = surface_from_dict({k: v for k, v in ASPHERE.items() if k != "coefficients"} | {"type": "conic"})
    asph = surface_from_dict({**ASPHERE, "coefficients": []})
    rho = np.linspace(0, 20, 11)
    np.testing.assert_allclose(asph.sag(rho), conic.sag(rho), rtol=1e-14, atol=1e-15)
    assert surface_from_dict(asph.to_dict()).to_dict() == asph.to_dict()
    assert asph.to_dict()["type"] == "asphere"


def _rotation_reference(ax, ay, az):
    """x first, then y, then z (extrinsic, about the world axes), written out element by element."""
    a, b, c = (math.radians(x) for x in (ax, ay, az))
    rx = [[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]]
    ry = [[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]]
    rz = [[math.cos(c), -math.sin(c), 0], [math.sin(c), math.cos(c), 0], [0, 0, 1]]

    def mul(m, n):
        return [[sum(m[i][k] * n[k][j] for k in range(3)) for j in range(3)] for i in range(3)]
    return np.array(mul(rz, mul(ry, rx)))


@pytest.mark.parametrize("kind", ["conic", "asphere", "plane", "cylinder"])
def test_tilt_and_offset_place_any_surface(kind):
    base = {"conic": {"type": "conic", "radius_mm": 100.0, "conic": -0.5, "outer_radius_mm": 10.0},
            "asphere": {**ASPHERE},
            "plane": {"type": "plane", "outer_radius_mm": 10.0},
            "cylinder": {"type": "cylinder", "radius_mm": 5.0, "length_mm": 20.0}}[kind]
    base = {**base, "vertex_mm": [1.0, 2.0, 3.0], "axis": [0.0, 0.0, 1.0]}
    placed = surface_from_dict({**base, "tilt_deg": [10.0, -20.0, 30.0], "offset_mm": [0.5, -4.0, 7.0]})
    r = _rotation_reference(10.0, -20.0, 30.0)
    np.testing.assert_allclose(placed.axis, r @ np.array([0.0, 0.0, 1.0]), atol=1e-14)
    np.testing.assert_allclose(placed.vertex_mm, [1.5, -2.0, 10.0], atol=1e-14)
    # a point of the unplaced surface, rotated about its vertex and moved, lies on the placed one
    plain = surface_from_dict(base)
    local = np.array([[3.0, 1.0, 0.0]])
    if kind == "cylinder":
        local = np.array([[5.0 * math.cos(0.3), 5.0 * math.sin(0.3), 4.0]])
    elif kind != "plane":
        local[0, 2] = plain.sag(np.array([math.hypot(3.0, 1.0)]))[0]
    world = plain.to_world(local)
    moved = (r @ (world[0] - plain.vertex_mm)) + plain.vertex_mm + np.array([0.5, -4.0, 7.0])
    assert abs(placed.implicit(placed.to_local(moved[None]))[0]) < 1e-10


def test_off_axis_paraboloid_placed_by_tilt_and_offset_focuses():
    """A parent paraboloid R = 400 (f = 200) tilted 12 deg about x and decentred: a collimated beam along
    the tilted axis, hitting the off-axis zone, passes within 1e-6 mm of the tilted focus."""
    table = {"type": "conic", "vertex_mm": [0.0, 0.0, 0.0], "axis": [0.0, 0.0, 1.0], "radius_mm": 400.0,
             "conic": -1.0, "outer_radius_mm": 60.0, "inner_radius_mm": 20.0,
             "tilt_deg": [12.0, 0.0, 0.0], "offset_mm": [0.0, 5.0, -3.0]}
    surf = surface_from_dict(table)
    part = analytic_part("oap", surf, "al", tolerance_mm=0.05)
    isect = EmbreeIntersector(part.vertices_mm[part.faces])
    r = _rotation_reference(12.0, 0.0, 0.0)
    axis = r @ np.array([0.0, 0.0, 1.0])
    vertex = np.array([0.0, 5.0, -3.0])
    rng = np.random.default_rng(1)
    n = 2000
    rad = rng.uniform(25.0, 55.0, n)
    phi = rng.uniform(0.2, 1.2, n)  # one off-axis zone
    local = np.column_stack([rad * np.cos(phi), rad * np.sin(phi), np.full(n, 300.0)])
    o = local @ r.T + vertex
    d = np.tile(-axis, (n, 1))
    tri, t0 = isect.intersect(o, d)
    assert np.all(tri >= 0)
    t, nrm, ok = surf.refine_hits(o, d, t0)
    assert np.all(ok)
    p = o + t[:, None] * d
    out = reflect(d, nrm)
    focus = vertex + 200.0 * axis
    v = focus - p
    miss = np.linalg.norm(v - np.einsum("ij,ij->i", v, out)[:, None] * out, axis=1)
    assert miss.max() < 1e-6, miss.max()


@pytest.mark.parametrize("table, message", [
    ({**ASPHERE, "coefficients": "A4"}, "coefficients"),
    ({**ASPHERE, "coefficients": [1.0, float("nan")]}, "coefficients"),
    ({**ASPHERE, "tilt_deg": [1.0, 2.0]}, "tilt_deg"),
    ({**ASPHERE, "offset_mm": [0.0, "a", 0.0]}, "offset_mm"),
    ({"type": "plane", "outer_radius_mm": 1.0, "coefficients": [1.0]}, "coefficients"),
])
def test_bad_asphere_and_placement_keys_are_one_line_errors(table, message):
    with pytest.raises(GeometryError, match=message) as err:
        surface_from_dict(table, where="scene.toml part 'l1'")
    assert "\n" not in str(err.value) and "l1" in str(err.value)


@pytest.mark.parametrize("kind", ["conic", "asphere", "plane", "cylinder"])
def test_a_placed_surface_round_trips_through_to_dict(kind):
    """to_dict writes the placement folded into vertex_mm and axis (the surfaces are symmetric about their
    axis, so nothing is lost): reading it back gives the same placed surface, not the offset applied twice."""
    base = {"conic": {"type": "conic", "radius_mm": 100.0, "conic": -0.5, "outer_radius_mm": 10.0},
            "asphere": {**ASPHERE},
            "plane": {"type": "plane", "outer_radius_mm": 10.0, "inner_radius_mm": 2.0},
            "cylinder": {"type": "cylinder", "radius_mm": 5.0, "length_mm": 20.0}}[kind]
    placed = surface_from_dict({**base, "vertex_mm": [1.0, 2.0, 3.0], "tilt_deg": [5.0, 0.0, -7.0],
                                "offset_mm": [0.0, 3.0, -1.0]})
    d = placed.to_dict()
    assert "offset_mm" not in d and "tilt_deg" not in d
    again = surface_from_dict(d)
    np.testing.assert_allclose(again.vertex_mm, placed.vertex_mm, atol=1e-14)
    np.testing.assert_allclose(again.axis, placed.axis, atol=1e-14)
    assert again.to_dict() == d
