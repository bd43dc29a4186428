"""The compiled Newton solve of specular paths (straylight.engine.specular_manifold_kernel) against its numpy
twin (specular_manifold.solve_numpy): on random endpoints for sequences of 1-3 vertices on a tilted conic,
a tilted asphere and a tilted plane, reflections and transmissions (eta != 1), from the deterministic start
and from the bare start (every row solved: many give up or leave the surface), the same ok flags and the
same roots (x, the points and normals to 1e-12 mm, a few rows to the stop rule's 2e-12 mm); the geometry term's Jacobians and the term itself the
same to rounding (central differences: 1e-16 / 1e-5 mm); a surface the kernel does not know goes to numpy.
"""
from dataclasses import dataclass

import numpy as np
import pytest

from geometry.analytic import Asphere, Conic, Plane
from straylight.engine import specular_manifold as sm
from straylight.engine import specular_manifold_kernel as kernel


def _axis(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


CONIC = Conic(vertex_mm=np.array([0.0, 0.0, 0.0]), axis=_axis([0.02, -0.01, 1.0]), radius_mm=80.0, conic=-0.5,
              outer_radius_mm=20.0)
ASPHERE = Asphere(vertex_mm=np.array([0.5, 0.0, 8.0]), axis=_axis([0.0, 0.03, 1.0]), radius_mm=-60.0, conic=0.0,
                  outer_radius_mm=20.0, coefficients=(1e-6, -2e-9))
PLANE = Plane(vertex_mm=np.array([0.0, 0.3, 15.0]), axis=_axis([0.05, 0.0, 1.0]), outer_radius_mm=25.0)
V = sm.Vertex
INTO_GLASS = dict(eta_front=1 / 1.5, eta_back=1.5, medium_front=-1, medium_back=0)
OUT_OF_GLASS = dict(eta_front=1.5, eta_back=1 / 1.5, medium_front=0, medium_back=-1)
SEQUENCES = {
    "R conic": (V(CONIC, True),),
    "R asphere": (V(ASPHERE, True),),
    "R plane": (V(PLANE, True),),
    "T conic": (V(CONIC, False, **INTO_GLASS),),
    "T asphere": (V(ASPHERE, False, **INTO_GLASS),),
    "T plane": (V(PLANE, False, **INTO_GLASS),),
    "T conic T asphere": (V(CONIC, False, **INTO_GLASS), V(ASPHERE, False, **OUT_OF_GLASS)),
    "T asphere R plane": (V(ASPHERE, False), V(PLANE, True)),
    "T conic R asphere T conic": (V(CONIC, False, **INTO_GLASS), V(ASPHERE, True, medium_front=-1, medium_back=0),
                                  V(CONIC, False, **INTO_GLASS)),
    "T conic T asphere T plane": (V(CONIC, False, **INTO_GLASS), V(ASPHERE, False, **OUT_OF_GLASS),
                                  V(PLANE, False, eta_front=1 / 1.3, eta_back=1.3)),
}
ROWS = 3000


def _endpoints(seed):
    rng = np.random.default_rng(seed)
    p = rng.uniform([-30.0, -30.0, -60.0], [30.0, 30.0, -20.0], (ROWS, 3))
    z = rng.uniform([-30.0, -30.0, -60.0], [30.0, 30.0, 60.0], (ROWS, 3))
    return p, z


@pytest.mark.parametrize("name", list(SEQUENCES))
def test_compiled_solve_finds_the_numpy_roots(name):
    seq = SEQUENCES[name]
    assert kernel.pack(seq) is not None
    p, z = _endpoints(len(name))
    x0, ok0 = sm.start(seq, p, z)
    runs = [(x0, ok0), (x0, ok0 & sm.plausible(seq, x0, p, z))]  # every row, and the rows the estimator solves
    for x_start, rows in runs:
        fast = sm.solve(seq, p, z, x_start, rows)
        ref = sm.solve_numpy(seq, p, z, x_start, rows)
        np.testing.assert_array_equal(fast.ok, ref.ok)
        ok = ref.ok
        # the solve stops at |F| <= 1e-14 (sines): with |dF/dx| down to 1 / (200 mm) that is up to 2e-12 mm
        # from the root, so a row whose twin rounds to the other side of it and takes one more step differs
        # by that much (1 row in 3000 here); the rest agree to 1e-12 mm
        for got, want in ((fast.x, ref.x), (fast.X, ref.X), (fast.N, ref.N)):
            diff = np.abs(got[ok] - want[ok]).max(axis=tuple(range(1, got.ndim)))
            assert diff.max(initial=0.0) <= 5e-12 and (diff > 1e-12).sum() <= 2
        assert np.isnan(fast.X[~ok]).all() and np.isnan(fast.N[~ok]).all()
    every = sm.solve_numpy(seq, p, z, x0, ok0)
    assert every.ok.sum() > 0.25 * ROWS and (ok0 & ~every.ok).sum() >= 20  # roots found, and rows that give up
    default = sm.solve(seq, p, z)  # the start and plausibility inside solve, as the estimator calls it
    np.testing.assert_array_equal(default.ok, sm.solve(seq, p, z, compiled=False).ok)


@pytest.mark.parametrize("name", ["R asphere", "T conic T asphere", "T conic R asphere T conic"])
def test_compiled_geometry_term_jacobians_agree(name, monkeypatch):
    seq = SEQUENCES[name]
    p, z = _endpoints(7)
    x0, ok0 = sm.start(seq, p, z)
    sol = sm.solve(seq, p, z, x0, ok0)
    g = sol.ok
    nz = _axis([0.1, -0.2, -1.0])[None, :].repeat(ROWS, axis=0)
    t, b = sm.orthonormal_basis(nz)
    fast = sm.implicit_jacobians(seq, sol.x, p, z, t, b)
    ref = sm.implicit_jacobians_numpy(seq, sol.x, p, z, t, b)
    for a, r in zip(fast, ref):  # central differences of numbers equal to rounding: 1e-15 / 1e-5
        np.testing.assert_allclose(a[g], r[g], rtol=0, atol=1e-8 * max(1.0, float(np.abs(r[g]).max())))
    J_fast, omega_fast = sm.implicit_geometry_term(seq, sol, p, z, nz)
    monkeypatch.setattr(sm, "implicit_jacobians", lambda *args: sm.implicit_jacobians_numpy(*args))
    J_ref, omega_ref = sm.implicit_geometry_term(seq, sol, p, z, nz)
    assert (J_ref[g] > 0).mean() > 0.9
    np.testing.assert_allclose(J_fast[g], J_ref[g], rtol=1e-6)
    np.testing.assert_array_equal(omega_fast[g], omega_ref[g])


@dataclass(frozen=True, eq=False)
class _Unexported(Conic):
    """A conic that does not export its sag: the compiled kernel does not know it."""

    sag_parameters = None


def test_a_surface_the_kernel_does_not_know_is_solved_in_numpy():
    mirror = _Unexported(vertex_mm=np.array([0.0, 0.0, 0.0]), axis=np.array([0.0, 0.0, 1.0]), radius_mm=80.0,
                         outer_radius_mm=20.0)
    seq = (V(mirror, True),)
    assert kernel.pack(seq) is None and kernel.pack((V(CONIC, True),)) is not None
    p, z = _endpoints(3)
    p[:, 2] = -p[:, 2]  # in front of the mirror
    z[:, 2] = np.abs(z[:, 2]) + 5.0
    sol = sm.solve(seq, p, z)
    ref = sm.solve(seq, p, z, compiled=False)
    assert sol.ok.sum() > ROWS // 4
    np.testing.assert_array_equal(sol.x, ref.x)  # the same numpy code: the same bits
    np.testing.assert_array_equal(sol.ok, ref.ok)
