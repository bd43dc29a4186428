"""Specular paths through one to four analytic surfaces, solved for (specular manifold connections).

Given a point P, a point z and a sequence S of k = 1 to 4 interfaces (each a part's analytic surface,
``geometry.analytic.Conic`` / ``Asphere`` / ``Plane``, with reflection or transmission), find the
points X_1 (.. X_k) on the surfaces such that P -> X_1 (-> .. X_k) -> z obeys the law of reflection or
refraction at every X_i, and the generalized geometry term |d omega_P / d A_z| of that path.

Unknowns: each X_i's local coordinates (u_i, v_i) in its surface's frame (X = (u, v, sag(rho)),
geometry.analytic). Constraint at X_i (Jakob & Marschner 2012, "Manifold exploration", eq. 4, in the
form of Snell's law for the tangential components): with omega_a, omega_b the unit directions from
X_i to the previous and the next vertex,

    reflection:    t_j . (omega_a + omega_b) = 0
    transmission:  t_j . (eta omega_a + omega_b) = 0,   eta = n_incident / n_transmitted,

for the two tangents t_1, t_2 of the surface at X_i (the local x and y axes projected on its tangent
plane): 2k equations, solved by Newton's method with a central-difference Jacobian and step halving,
from a deterministic start (:func:`start`: the straight line from P to z's image unfolded through the
reflecting surfaces' vertex planes, met with each surface's vertex plane): the solution is a function
of (P, z, S) alone, so the balance weights of the estimator that uses it can be recomputed for any
path (straylight.engine.specular_nee).

Geometry term (Hanika, Droske & Fascione 2015, "Manifold next event estimation", sec. 4, by the
implicit function theorem): with F(x; z) = 0 at the solution, dx/dz = -(dF/dx)^-1 dF/dz (both by
central differences, z moved along the two tangents of the detector at z), dX_1/dz from the
parametrisation, d omega/dz = (I - omega omega^T) dX_1/dz / |X_1 - P| and |d omega/dA_z| = |d omega/da
x d omega/db|. For no interface at all this is cos_z / d^2 (next-event estimation's term); for a
plane mirror cos_z / d'^2 with d' the unfolded length (tests/straylight/test_specular_nee.py).

Compiled: the Newton iteration and the geometry term's Jacobians run per row in
straylight.engine.specular_manifold_kernel for conics, aspheres and planes (their numpy twins here,
:func:`solve_numpy` and :func:`implicit_jacobians_numpy`, do any other surface: the same roots and ok
flags, tests/straylight/test_specular_manifold_kernel.py).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from straylight.engine import specular_manifold_kernel as kernel
from straylight.sources import orthonormal_basis

NEWTON_ITER = 20
GIVE_UP_AFTER = 5  # iterations after which a row still far from a root stops
GIVE_UP_RESIDUAL = 1e-4  # (specular_nee's ghosts give up only above 1e-2: GHOST_GIVE_UP_RESIDUAL there)
NEWTON_TOL_MM = 1e-10  # a converged step, mm
RESIDUAL_TOL = 1e-9  # |F| of an accepted solution (dimensionless: sines)
DIFF_MM = 1e-5  # central-difference step in (u, v), mm
DIFF_Z_MM = 1e-4  # central-difference step of z along the detector, mm


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


def _unit(v):
    n = np.sqrt(np.einsum("ij,ij->i", v, v))
    return v / np.where(n > 0, n, 1.0)[:, None], n


class Vertex(NamedTuple):
    """One interface of a sequence: its analytic surface, reflection (True) or transmission,
    eta = n_incident / n_transmitted for light arriving on its front (``eta_front``) or back side, and
    the medium on each side (-1: the surrounding air; a dielectric's back is its glass)."""

    surface: object
    reflect: bool
    eta_front: float = 1.0
    eta_back: float = 1.0
    medium_front: int = -1
    medium_back: int = -1


def media_agree(seq, arrive_front) -> np.ndarray:
    """Per row: the light leaves p in the air, crosses each medium it enters to the next vertex and ends
    in the air at z; ``arrive_front`` (m, k) bool, the side of each vertex the light arrives on."""
    m = arrive_front.shape[0]
    ok = np.ones(m, dtype=bool)
    medium = np.full(m, -1)
    for i, vtx in enumerate(seq):
        front = arrive_front[:, i]
        arrive = np.where(front, vtx.medium_front, vtx.medium_back)
        ok &= arrive == medium
        leave_front = front if vtx.reflect else ~front
        medium = np.where(leave_front, vtx.medium_front, vtx.medium_back)
    return ok & (medium == -1)


def surface_points(surface, uv):
    """World points (m, 3) and front unit normals (m, 3) at local coordinates ``uv`` (m, 2)."""
    rho = np.hypot(uv[:, 0], uv[:, 1])
    with np.errstate(invalid="ignore"):
        h = surface.sag(rho)
    local = np.column_stack([uv[:, 0], uv[:, 1], h])
    world = surface.to_world(local)
    with np.errstate(invalid="ignore", divide="ignore"):
        g = surface.gradient(local) * surface.front_sign()
        g = g / np.sqrt(np.einsum("ij,ij->i", g, g))[:, None]
    return world, surface.dirs_to_world(g)


def _points(seq, x):
    """The vertices X (m, k, 3) and their front normals (m, k, 3) at unknowns ``x`` (m, 2k)."""
    m = len(x)
    X = np.empty((m, len(seq), 3))
    N = np.empty((m, len(seq), 3))
    for i, vtx in enumerate(seq):
        X[:, i], N[:, i] = surface_points(vtx.surface, x[:, 2 * i:2 * i + 2])
    return X, N


def _constraint(seq, i, X, N, p, z):
    """F's two rows (m, 2) of vertex i: its tangents dotted with omega_a + omega_b (eta omega_a + omega_b)."""
    k = len(seq)
    vtx = seq[i]
    prev = p if i == 0 else X[:, i - 1]
    nxt = z if i == k - 1 else X[:, i + 1]
    wa, _ = _unit(prev - X[:, i])
    wb, _ = _unit(nxt - X[:, i])
    n = N[:, i]
    if vtx.reflect:
        h = wa + wb
    else:
        eta = np.where(_dot(wa, n) > 0, vtx.eta_front, vtx.eta_back)
        h = eta[:, None] * wa + wb
    # t_j . h with t_j = r_j - (n . r_j) n, the local axis r_j projected on the tangent plane
    rot = vtx.surface.rotation[:2]
    return h @ rot.T - (n @ rot.T) * _dot(n, h)[:, None]


def residual(seq, x, p, z):
    """F (m, 2k) of the sequence ``seq`` at unknowns ``x`` (m, 2k), endpoints p, z (m, 3); also the
    vertices X (m, k, 3) and their front normals (m, k, 3)."""
    X, N = _points(seq, x)
    F = np.empty((len(x), 2 * len(seq)))
    for i in range(len(seq)):
        F[:, 2 * i:2 * i + 2] = _constraint(seq, i, X, N, p, z)
    return F, X, N


def _moved(seq, c, x, X, N, p, z, step):
    """The rows of F that change when unknown ``c`` moves by ``step`` (those of its vertex i and its
    neighbours; F's other rows do not depend on it), as (first row, rows): each row is the same number
    :func:`residual` gives there."""
    i = c // 2
    xs = x[:, 2 * i:2 * i + 2].copy()
    xs[:, c % 2] += step
    X2, N2 = X.copy(), N.copy()
    X2[:, i], N2[:, i] = surface_points(seq[i].surface, xs)
    lo, hi = max(i - 1, 0), min(i + 1, len(seq) - 1)
    return 2 * lo, np.concatenate([_constraint(seq, j, X2, N2, p, z) for j in range(lo, hi + 1)], axis=1)


def _jacobian(seq, x, p, z, F=None):
    """dF/dx (m, 2k, 2k): central differences, or forward differences from ``F`` = F(x) when given (the
    Newton steps' Jacobian only steers; the geometry term takes the central one). Moving an unknown of
    vertex i changes only the rows of vertices i - 1 .. i + 1 (the others' differences are exactly 0)."""
    m, d = x.shape
    J = np.zeros((m, d, d))
    X, N = _points(seq, x)
    for c in range(d):
        lo, Fp = _moved(seq, c, x, X, N, p, z, DIFF_MM)
        rows = slice(lo, lo + Fp.shape[1])
        if F is not None:
            J[:, rows, c] = (Fp - F[:, rows]) / DIFF_MM
            continue
        _lo, Fm = _moved(seq, c, x, X, N, p, z, -DIFF_MM)
        J[:, rows, c] = (Fp - Fm) / (2 * DIFF_MM)
    return J


def _mirror(points, vertex, axis):
    return points - 2.0 * ((points - vertex) @ axis)[:, None] * axis[None, :]


def start(seq, p, z):
    """The deterministic start (m, 2k): the straight line from p to z's image in the reflecting
    surfaces' vertex planes (the path unfolded), met with each surface's (unfolded) vertex plane, the
    points folded back and taken in each surface's local (u, v); ``ok`` False where a plane is parallel."""
    m = len(p)
    k = len(seq)
    planes = [(np.asarray(v.surface.vertex_mm, float), np.asarray(v.surface.axis, float)) for v in seq]

    def unfold(points, upto):  # the mirrors of the reflections before vertex `upto`, innermost last
        out = points
        for i in reversed(range(upto)):
            if seq[i].reflect:
                out = _mirror(out, *planes[i])
        return out

    z_img = unfold(z, k)
    d = z_img - p
    x = np.zeros((m, 2 * k))
    ok = np.ones(m, dtype=bool)
    for i, vtx in enumerate(seq):
        v0, a = planes[i]
        # the plane of surface i, unfolded by the reflections before it
        pts = np.stack([v0, v0 + a])
        img = unfold(pts, i)
        v0u, au = img[0], img[1] - img[0]
        denom = d @ au
        good = np.abs(denom) > 1e-12
        t = np.where(good, ((v0u - p) @ au) / np.where(good, denom, 1.0), 0.0)
        if not any(v.reflect for v in seq[:i]) and hasattr(vtx.surface, "refine_hits"):
            # no mirror before it: the line meets the surface itself (near a curved rim the vertex plane
            # is far from it: a point just in front of the rim is behind the vertex plane)
            length = np.linalg.norm(d, axis=1)
            unit = d / np.where(length > 0, length, 1.0)[:, None]
            with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
                t_s, _n, on = vtx.surface.refine_hits(np.ascontiguousarray(p), np.ascontiguousarray(unit),
                                                      np.where(np.isfinite(t), t * length, 0.0))
            on &= np.isfinite(t_s) & (t_s > 0)
            t = np.where(on, t_s / np.where(length > 0, length, 1.0), t)
        y = p + t[:, None] * d
        # fold back: the mirrors in the same order (each is its own inverse; applied outermost first)
        for j in range(i):
            if seq[j].reflect:
                y = _mirror(y, *planes[j])
        ok &= good
        x[:, 2 * i:2 * i + 2] = vtx.surface.to_local(y)[:, :2]
    return x, ok


def plausible(seq, x0, p, z):
    """Rows whose start is worth solving from: every start point within twice its surface's reach from
    the axis, and the path through the start points (put on the surfaces) on each surface's side that
    its branch needs there (a reflection returns to the side it came from, a transmission crosses; the
    tangent plane at the start point, not the vertex plane: a point just in front of a curved surface's
    rim is behind its vertex plane), starting and ending in the air. A deterministic part of the
    solve: the rows it drops are paths this estimator does not make (the split trees keep them)."""
    ok = np.ones(len(p), dtype=bool)
    k = len(seq)
    pts, nrm = [], []
    with np.errstate(invalid="ignore", divide="ignore"):
        for i, vtx in enumerate(seq):
            X, n = surface_points(vtx.surface, x0[:, 2 * i:2 * i + 2])
            pts.append(X)
            nrm.append(n)
        front = np.zeros((len(p), k), dtype=bool)
        for i, vtx in enumerate(seq):
            surf = vtx.surface
            reach = surf.rho_range_mm()[1] if hasattr(surf, "rho_range_mm") else getattr(surf, "outer_radius_mm", np.inf)
            ok &= np.hypot(x0[:, 2 * i], x0[:, 2 * i + 1]) <= 2.0 * float(reach)
            prev = p if i == 0 else pts[i - 1]
            nxt = z if i == k - 1 else pts[i + 1]
            sa, sb = _dot(prev - pts[i], nrm[i]), _dot(nxt - pts[i], nrm[i])
            ok &= np.isfinite(sa) & np.isfinite(sb)
            ok &= ((sa > 0) == (sb > 0)) if vtx.reflect else ((sa > 0) != (sb > 0))
            front[:, i] = sa > 0
    return ok & media_agree(seq, front)


class Solution(NamedTuple):
    x: np.ndarray  # (m, 2k) local coordinates
    X: np.ndarray  # (m, k, 3) the interface points
    N: np.ndarray  # (m, k, 3) their front normals
    ok: np.ndarray  # (m,) converged to a finite solution


def solve(seq, p, z, x0=None, ok0=None, compiled: bool = True, give_up_residual: float = GIVE_UP_RESIDUAL) -> Solution:
    """Newton's method for the sequence ``seq`` between p and z (m, 3) from ``x0`` (default
    :func:`start`). Rows are independent: each row's iterates do not depend on the others. Compiled
    (straylight.engine.specular_manifold_kernel.solve_rows) when every surface is a conic, asphere or
    plane, else (or ``compiled=False``) :func:`solve_numpy`, its twin: the same roots and ok flags.
    ``give_up_residual``: the residual above which a row stops after :data:`GIVE_UP_AFTER` iterations."""
    if x0 is None:
        x0, ok0 = start(seq, p, z)
        ok0 = ok0 & plausible(seq, x0, p, z)
    par = kernel.pack(seq) if compiled else None
    if par is None:
        return solve_numpy(seq, p, z, x0, ok0, give_up_residual)
    x = np.array(x0, dtype=float)
    m, k = len(x), len(seq)
    active = np.ones(m, bool) if ok0 is None else np.asarray(ok0, bool).copy()
    X = np.empty((m, k, 3))
    N = np.empty((m, k, 3))
    ok = np.empty(m, bool)
    kernel.solve_rows(par, np.ascontiguousarray(p, dtype=float), np.ascontiguousarray(z, dtype=float), x, active,
                      NEWTON_ITER, GIVE_UP_AFTER, float(give_up_residual), NEWTON_TOL_MM, RESIDUAL_TOL, DIFF_MM, X, N, ok)
    return Solution(x, X, N, ok)


SHOOT_ITER = 20  # Newton (Broyden) steps of a shot's first vertex
SHOOT_DIFF_MM = 1e-6  # forward-difference step of the first vertex's (u, v), mm
LAND_TOL_MM = 1e-9  # a shot lands on z this well
BROYDEN = True  # the shots' Jacobian updated by the secant rule after the first (11 traces a row, against 14)


class Shot(NamedTuple):
    solution: Solution
    J: np.ndarray  # (m,) |d omega_P / dA_z|, sr / mm^2
    omega: np.ndarray  # (m, 3) unit direction from p to X_1
    shots: np.ndarray  # (m,) the traces each row took


def shoot(seq, p, z, nz) -> Shot | None:
    """The sequence's paths from p to z (detector normals ``nz``) by shooting: Newton's method on the first
    vertex's local (u, v) alone, each trial traced through the sequence (every later vertex found by meeting its
    surface, reflected or refracted by its law) onto the plane through z (specular_manifold_kernel.shoot_rows),
    from the first surface's vertex (else :func:`start`'s first vertex, pulled toward the axis: the kernel's
    fallbacks); the geometry term from the same shots at the root. Two unknowns instead of 2k: for the ghosts' four
    vertices ~3x cheaper than :func:`solve` and its implicit geometry term (11 traces, ~9 us a row against ~29 on
    the guide scope). A deterministic function of (p, z, sequence). None where a surface is not one the kernel
    knows."""
    par = kernel.pack(seq)
    if par is None:
        return None
    m, k = len(p), len(seq)
    x0, ok0 = start(seq, p, z)  # (the kernel's fallback after the vertex; no plausibility gate: a shot that
    x = np.array(x0, dtype=float)  # misses a surface fails by itself)
    ok0 = np.ones(m, bool)
    e1, e2 = orthonormal_basis(np.asarray(nz, dtype=float))
    X = np.empty((m, k, 3))
    N = np.empty((m, k, 3))
    J = np.empty(m)
    ok = np.empty(m, bool)
    shots = np.zeros(m, np.int64)
    kernel.shoot_rows(par, np.ascontiguousarray(p, dtype=float), np.ascontiguousarray(z, dtype=float),
                      np.ascontiguousarray(nz, dtype=float), np.ascontiguousarray(e1), np.ascontiguousarray(e2), x,
                      ok0, SHOOT_ITER, SHOOT_DIFF_MM, LAND_TOL_MM, BROYDEN, X, N, J, ok, shots)
    omega, _ = _unit(np.where(ok[:, None], X[:, 0] - p, 1.0))
    return Shot(Solution(x, X, N, ok), J, omega, shots)


def solve_numpy(seq, p, z, x0, ok0=None, give_up_residual: float = GIVE_UP_RESIDUAL) -> Solution:
    """:func:`solve` in numpy, all rows at once (the compiled kernel's twin; any surface with sag,
    gradient and frame)."""
    x = np.array(x0, dtype=float)
    m = len(x)
    active = np.ones(m, bool) if ok0 is None else np.asarray(ok0, bool).copy()
    done = np.zeros(m, bool)
    F = np.full((m, x.shape[1]), np.inf)
    norm = np.full(m, np.inf)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        a = np.flatnonzero(active)
        if len(a):
            F[a] = residual(seq, x[a], p[a], z[a])[0]
            norm[a] = np.linalg.norm(F[a], axis=1)
        active &= np.isfinite(norm)
        done = active & (norm <= 1e-14)  # an exact start (a plane mirror's image)
        for it in range(NEWTON_ITER):
            a = np.flatnonzero(active & ~done)
            if len(a) == 0:
                break
            J = _jacobian(seq, x[a], p[a], z[a], F[a])
            good = np.isfinite(J).all(axis=(1, 2)) & (np.abs(np.linalg.det(J)) > 1e-300)
            active[a[~good]] = False
            a = a[good]
            if len(a) == 0:
                break
            step = -np.linalg.solve(J[good], F[a][:, :, None])[:, :, 0]
            scale = np.ones(len(a))
            new_x = x[a] + step
            new_F = residual(seq, new_x, p[a], z[a])[0]
            new_norm = np.linalg.norm(new_F, axis=1)
            for _h in range(8):  # halve the step while the residual grows (or leaves the surface)
                worse = ~(new_norm <= norm[a]) & (np.linalg.norm(F[a], axis=1) > RESIDUAL_TOL)
                if not worse.any():
                    break
                w = np.flatnonzero(worse)
                scale[w] *= 0.5
                new_x[w] = x[a[w]] + scale[w, None] * step[w]
                new_F[w] = residual(seq, new_x[w], p[a[w]], z[a[w]])[0]
                new_norm[w] = np.linalg.norm(new_F[w], axis=1)
            moved = np.max(np.abs(new_x - x[a]), axis=1)
            x[a], F[a], norm[a] = new_x, new_F, new_norm
            done[a] = (moved <= NEWTON_TOL_MM) | (new_norm <= 1e-14)
            active[a] &= np.isfinite(new_norm)
            if it >= GIVE_UP_AFTER:  # not near a root by now: no solution from this start
                active[a] &= new_norm <= give_up_residual
        ok = active & np.isfinite(norm) & (norm <= RESIDUAL_TOL)
        X = np.full((m, len(seq), 3), np.nan)
        N = np.full((m, len(seq), 3), np.nan)
        g = np.flatnonzero(ok)
        if len(g):
            _, X[g], N[g] = residual(seq, x[g], p[g], z[g])
    ok &= np.isfinite(X).all(axis=(1, 2))
    return Solution(x, X, N, ok)


def geometry_term(seq, sol: Solution, p, z, nz):
    """|d omega_P / d A_z| (sr / mm^2) of the solved paths (implicit function theorem, module doc) and
    the unit direction omega_P (m, 3) from p to X_1; ``nz`` the detector normals at z. One reflection
    in a plane: |cos_z| / d'^2 with d' the unfolded length (the image of z), exactly."""
    k = len(seq)
    if k == 1 and seq[0].reflect and getattr(seq[0].surface, "kind", "") == "plane":
        omega, d1 = _unit(sol.X[:, 0] - p)
        arrive, d2 = _unit(z - sol.X[:, 0])
        return np.abs(_dot(arrive, nz)) / (d1 + d2) ** 2, omega
    return implicit_geometry_term(seq, sol, p, z, nz)


def implicit_geometry_term(seq, sol: Solution, p, z, nz):
    """:func:`geometry_term` by the implicit function theorem, for any sequence."""
    m = len(p)
    k = len(seq)
    t, b = orthonormal_basis(nz)  # any orthonormal tangents: |d omega/dt x d omega/db| does not depend on them
    with np.errstate(invalid="ignore", divide="ignore"):
        Jx, Jz, dX = implicit_jacobians(seq, sol.x, p, z, t, b)
        good = np.isfinite(Jx).all(axis=(1, 2)) & (np.abs(np.linalg.det(Jx)) > 1e-300)
        dx = np.zeros((m, 2 * k, 2))
        if good.any():
            dx[good] = -np.linalg.solve(Jx[good], Jz[good])
        dX1 = np.einsum("mic,mcj->mij", dX, dx[:, 0:2, :])
        omega, length = _unit(sol.X[:, 0] - p)
        proj = np.eye(3)[None, :, :] - omega[:, :, None] * omega[:, None, :]
        dw = np.einsum("mij,mjc->mic", proj, dX1) / np.where(length > 0, length, 1.0)[:, None, None]
        J = np.linalg.norm(np.cross(dw[:, :, 0], dw[:, :, 1]), axis=1)
    J = np.where(good & np.isfinite(J), J, 0.0)
    return J, omega


def implicit_jacobians(seq, x, p, z, t, b, compiled: bool = True):
    """The central-difference dF/dx (m, 2k, 2k), dF/dz along the detector tangents t, b (m, 2k, 2) and
    dX_1/d(u_1, v_1) (m, 3, 2) of :func:`implicit_geometry_term`: compiled
    (specular_manifold_kernel.jacobians_rows) where the surfaces allow, else :func:`implicit_jacobians_numpy`."""
    par = kernel.pack(seq) if compiled else None
    if par is None:
        return implicit_jacobians_numpy(seq, x, p, z, t, b)
    m, d = x.shape
    Jx, Jz, dX = np.empty((m, d, d)), np.empty((m, d, 2)), np.empty((m, 3, 2))

    def c(a):
        return np.ascontiguousarray(a, dtype=float)

    kernel.jacobians_rows(par, c(x), c(p), c(z), c(t), c(b), DIFF_MM, DIFF_Z_MM, Jx, Jz, dX)
    return Jx, Jz, dX


def implicit_jacobians_numpy(seq, x, p, z, t, b):
    """:func:`implicit_jacobians` in numpy (the compiled kernel's twin)."""
    m, k = len(x), len(seq)
    with np.errstate(invalid="ignore", divide="ignore"):
        Jx = _jacobian(seq, x, p, z)
        Jz = np.zeros((m, 2 * k, 2))  # z enters only the last vertex's rows
        X, N = _points(seq, x)
        for c, e in enumerate((t, b)):
            Jz[:, 2 * k - 2:, c] = (_constraint(seq, k - 1, X, N, p, z + DIFF_Z_MM * e)
                                    - _constraint(seq, k - 1, X, N, p, z - DIFF_Z_MM * e)) / (2 * DIFF_Z_MM)
        s1 = seq[0].surface
        dX = np.zeros((m, 3, 2))
        for c in range(2):
            up, um = x[:, 0:2].copy(), x[:, 0:2].copy()
            up[:, c] += DIFF_MM
            um[:, c] -= DIFF_MM
            dX[:, :, c] = (surface_points(s1, up)[0] - surface_points(s1, um)[0]) / (2 * DIFF_MM)
    return Jx, Jz, dX


def side_checks(seq, sol: Solution, p, z):
    """Per row: every X_i inside its surface's valid region and clear aperture, reflections leave on
    the side they arrive from and transmissions cross."""
    ok = sol.ok.copy()
    k = len(seq)
    front = np.zeros((len(p), k), dtype=bool)
    for i, vtx in enumerate(seq):
        Xi, n = sol.X[:, i], sol.N[:, i]
        prev = p if i == 0 else sol.X[:, i - 1]
        nxt = z if i == k - 1 else sol.X[:, i + 1]
        a = _dot(prev - Xi, n)
        b = _dot(nxt - Xi, n)
        same = (a > 0) == (b > 0)
        ok &= (same if vtx.reflect else ~same) & (a != 0) & (b != 0)
        front[:, i] = a > 0
        with np.errstate(invalid="ignore"):
            ok &= vtx.surface.valid(vtx.surface.to_local(np.where(np.isfinite(Xi), Xi, 0.0)))
    return ok & media_agree(seq, front)
