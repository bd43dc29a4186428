"""``asphere`` with ``power_terms`` (odd powers and r^2: a Zemax extended odd asphere, docs/reference/scene.md),
checked like the even asphere in test_asphere_and_placement.py against references written here: the sag as
the printed formula term by term in plain Python, hits as the bisection root of sag(rho(t)) - z(t) along
each ray (no derivative, no mesh), normals as a central finite difference of that sag."""
import math

import numpy as np
import pytest

from geometry.analytic import surface_from_dict
from geometry.mesh import GeometryError

from test_asphere_and_placement import check_hits_and_normals

# a Fujinon-like odd asphere: r^3 and r^5 terms of the size real files carry (XF27mm F2.8: -7e-3, -2.2e-2 on a
# 4.45 mm aperture), scaled to this 20 mm one, and an r^1 term (a shallow cone's tip)
TERMS = [[1, 2.0e-3], [3, -1.5e-5], [5, 4.0e-9], [7, -2.0e-12]]
ODD = {"type": "asphere", "vertex_mm": [0.0, 0.0, 0.0], "axis": [0.0, 0.0, 1.0], "radius_mm": 40.0,
       "conic": -0.6, "coefficients": [2.0e-6, -3.0e-9], "power_terms": TERMS, "outer_radius_mm": 20.0}


def _sag_reference(rho, radius=40.0, k=-0.6, coefs=(2.0e-6, -3.0e-9), terms=TERMS):
    c = 1.0 / radius
    h = c * rho * rho / (1.0 + math.sqrt(1.0 - (1.0 + k) * c * c * rho * rho))
    for i, a in enumerate(coefs):
        h += a * rho ** (2 * i + 4)
    for p, a in terms:
        h += a * rho ** p
    return h


def test_power_terms_sag_is_the_printed_formula():
    s = surface_from_dict(ODD)
    for rho in (0.0, 0.5, 3.0, 11.0, 19.9):
        assert s.sag(np.array([rho]))[0] == pytest.approx(_sag_reference(rho), rel=1e-13, abs=1e-15)
    # the odd terms matter: at the edge they move the surface by far more than a micron
    assert abs(s.sag(np.array([19.9]))[0] - _sag_reference(19.9, terms=[])) > 1e-2


def test_power_terms_hits_and_normals_against_bisection_and_finite_differences():
    # off the cone's tip (r >= 0.2 mm), where the normal is not defined
    check_hits_and_normals(ODD, _sag_reference, tolerance_mm=0.01, seed=5, r_min=0.2, eps=1e-6)


def test_even_power_terms_are_the_even_coefficients():
    """[[4, A4], [6, A6]] as power terms is the same surface as coefficients = [A4, A6] (same sag and hits)."""
    even = surface_from_dict({**ODD, "power_terms": [], "coefficients": [2.0e-6, -3.0e-9]})
    as_terms = surface_from_dict({**ODD, "coefficients": [], "power_terms": [[4, 2.0e-6], [6, -3.0e-9]]})
    rho = np.linspace(0, 20, 41)
    np.testing.assert_allclose(as_terms.sag(rho), even.sag(rho), rtol=1e-13, atol=1e-15)
    o = np.column_stack([np.linspace(-15, 15, 31), np.full(31, 2.0), np.full(31, 30.0)])
    d = np.tile([0.0, 0.0, -1.0], (31, 1))
    t0 = np.full(31, 30.0)
    t1, n1, ok1 = even.refine_hits(o, d, t0)
    t2, n2, ok2 = as_terms.refine_hits(o, d, t0)
    assert ok1.all() and ok2.all()
    np.testing.assert_allclose(t2, t1, atol=1e-12)
    np.testing.assert_allclose(n2, n1, atol=1e-12)


def test_power_terms_round_trip_and_compiled_solve_declines():
    s = surface_from_dict(ODD)
    assert surface_from_dict(s.to_dict()).to_dict() == s.to_dict()
    assert s.to_dict()["power_terms"] == TERMS
    assert s.sag_parameters() is None  # the specular-manifold kernel's sag knows even terms only: numpy solves it
    assert surface_from_dict({**ODD, "power_terms": []}).sag_parameters() is not None


@pytest.mark.parametrize("bad, words", [
    ([[0, 1e-3]], "integer >= 1"),
    ([[3.0, 1e-3]], "integer >= 1"),
    ([3, 1e-3], "pairs"),
    ([[3, "x"]], "pairs"),
    ([[3, float("nan")]], "pairs"),
    ([[3, 1e-3], [3, 2e-3]], "more than once"),
])
def test_bad_power_terms_are_one_line_errors(bad, words):
    with pytest.raises(GeometryError) as err:
        surface_from_dict({**ODD, "power_terms": bad}, where="part 'lens'")
    msg = str(err.value)
    assert "part 'lens'" in msg and "power_terms" in msg and words in msg and "\n" not in msg
