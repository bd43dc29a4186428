"""Off-axis segments (docs/reference/scene.md, ``aperture_center_mm``, ``aperture_half_widths_mm``): the clear
aperture of a conic or asphere centred off its axis, optionally a rectangle, as lens files write them for
off-axis mirrors. Checked against the paraboloid's focus (every ray parallel to the axis reflects through
R / 2, Born & Wolf §4.10) and against the aperture's own definition on a grid of rays."""
import math

import numpy as np
import pytest

from geometry.analytic import surface_from_dict
from geometry.mesh import GeometryError

OAP = {"type": "conic", "vertex_mm": [0.0, 0.0, 0.0], "axis": [0.0, 0.0, 1.0], "radius_mm": 1000.0, "conic": -1.0,
       "outer_radius_mm": 25.4, "aperture_center_mm": [0.0, 190.6, 0.0]}


def _down(x, y, z=300.0):
    o = np.column_stack([x, y, np.full(len(x), z)])
    return o, np.tile([0.0, 0.0, -1.0], (len(x), 1))


def _hits(surf, o, d):
    """The exact hits of rays found on the surface's own mesh (as the tracer does: mesh, then refine)."""
    import trimesh

    v, f = surf.mesh(0.01)
    mesh = trimesh.Trimesh(v, f, process=False)
    t0 = np.full(len(o), np.nan)
    loc, ray, _ = mesh.ray.intersects_location(o, d, multiple_hits=False)
    t0[ray] = np.einsum("ij,ij->i", loc - o[ray], d[ray])
    found = np.isfinite(t0)
    t, n, ok = surf.refine_hits(o[found], d[found], t0[found])
    return found, t, n, ok


def test_an_off_axis_paraboloid_segment_focuses_at_its_parent_focus():
    surf = surface_from_dict(OAP)
    rng = np.random.default_rng(1)
    r = 25.0 * np.sqrt(rng.random(400))
    a = 2 * math.pi * rng.random(400)
    o, d = _down(r * np.cos(a), 190.6 + r * np.sin(a))
    found, t, n, ok = _hits(surf, o, d)
    assert found.mean() > 0.99 and ok.all()  # the mesh covers the segment, every hit is inside it
    hit = o[found] + t[:, None] * d[found]
    out = d[found] - 2 * np.einsum("ij,ij->i", d[found], n)[:, None] * n
    s = (500.0 - hit[:, 2]) / out[:, 2]
    focus = hit + s[:, None] * out
    assert np.abs(focus[:, :2]).max() < 1e-6  # through (0, 0, R / 2) within 1e-6 mm


def test_only_rays_inside_the_decentred_rectangle_are_kept():
    surf = surface_from_dict({**OAP, "outer_radius_mm": math.hypot(10.0, 20.0), "aperture_half_widths_mm": [10.0, 20.0]})
    g = np.linspace(-30.0, 30.0, 41)
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    o, d = _down(x, 190.6 + y)
    t0 = (300.0 - surf.sag(np.hypot(o[:, 0], o[:, 1]))) + 0.01  # start beside the surface: refine onto it
    _, _, ok = surf.refine_hits(o, d, t0)
    expected = (np.abs(x) <= 10.0) & (np.abs(y) <= 20.0)
    assert np.array_equal(ok, expected)


def test_the_rectangle_turns_with_its_x_axis():
    surf = surface_from_dict({**OAP, "outer_radius_mm": math.hypot(10.0, 20.0), "aperture_half_widths_mm": [10.0, 20.0],
                              "aperture_x_axis": [0.0, 1.0, 0.0]})  # hx now along y
    o, d = _down(np.array([15.0, 0.0]), 190.6 + np.array([0.0, 15.0]))
    t0 = (300.0 - surf.sag(np.hypot(o[:, 0], o[:, 1]))) + 0.01
    assert surf.refine_hits(o, d, t0)[2].tolist() == [True, False]


def test_the_aperture_moves_with_the_surface_and_survives_a_round_trip():
    tilted = surface_from_dict({**OAP, "tilt_deg": [90.0, 0.0, 0.0], "offset_mm": [5.0, 0.0, 0.0]})
    again = surface_from_dict(tilted.to_dict())
    # the tilt turns (0, 190.6, 0) about x by 90 deg to (0, 0, 190.6), then the offset moves it by 5 in x
    assert again.to_dict()["aperture_center_mm"] == pytest.approx([5.0, 0.0, 190.6], abs=1e-9)
    assert again.aperture_center_uv == pytest.approx(tilted.aperture_center_uv, abs=1e-9)


@pytest.mark.parametrize("bad, words", [
    ({"aperture_half_widths_mm": [0.0, 1.0]}, "aperture_half_widths_mm"),
    ({"aperture_x_axis": [1.0, 0.0, 0.0]}, "needs 'aperture_half_widths_mm'"),
    ({"aperture_center_mm": [0.0, 990.0, 0.0], "conic": 0.0}, "no sag beyond"),
    ({"aperture_center_mm": [0.0, 1.0]}, "aperture_center_mm"),
])
def test_bad_off_axis_apertures_are_refused_in_one_line(bad, words):
    with pytest.raises(GeometryError, match=words) as err:
        surface_from_dict({**OAP, **bad})
    assert "\n" not in str(err.value)


def test_plane_surfaces_do_not_take_an_off_axis_aperture():
    with pytest.raises(GeometryError, match="unknown surface key"):
        surface_from_dict({"type": "plane", "vertex_mm": [0, 0, 0], "axis": [0, 0, 1], "outer_radius_mm": 5.0,
                           "aperture_center_mm": [1.0, 0.0, 0.0]})
