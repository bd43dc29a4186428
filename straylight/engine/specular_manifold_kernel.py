"""Compiled twin of straylight.engine.specular_manifold's Newton solve and of the Jacobians of its geometry
term: one row (one path P -> X_1 .. X_k -> z) per loop pass, the same arithmetic as the numpy code
(:func:`specular_manifold.solve_numpy`, :func:`specular_manifold.implicit_jacobians_numpy`): the residual
of Jakob & Marschner 2012 eq. 4 at each vertex, the forward-difference Jacobian (step ``DIFF_MM``, only
the rows of a moved vertex and its neighbours), Gaussian elimination with partial pivoting (LAPACK's
``getrf``/``getrs`` order), the same step halving and give-up rules. The same roots and ok flags as the
numpy code, x to rounding (tests/straylight/test_specular_manifold_kernel.py).

Surfaces: the analytic conic, asphere and plane (``geometry.analytic``: the sag
``h = c rho^2 / (1 + sqrt(1 - (1 + k) c^2 rho^2)) + sum A_n rho^n``), one row of ``par`` per vertex
(:func:`pack`): ``[kind, c, k, front_sign, reflect, eta_front, eta_back, R (9, rows u, v, w), vertex (3),
n_coef, A_4, A_6, ...]`` (kind 0 conic or plane, 1 asphere).
"""
from __future__ import annotations

import math

import numpy as np
from materials.jit_cache import njit

KIND, C, CONIC, SIGN, REFLECT, ETA_FRONT, ETA_BACK, ROT, VERTEX, NCOEF, COEF = 0, 1, 2, 3, 4, 5, 6, 7, 16, 19, 20


def pack(seq) -> np.ndarray | None:
    """The parameters (k, 20 + n_coef) of a sequence of ``specular_manifold.Vertex``, or None when a
    surface is not one the kernel knows (a cylinder, an asphere with power terms: the numpy code solves it)."""
    rows = []
    for vtx in seq:
        params = getattr(vtx.surface, "sag_parameters", None)
        got = None if params is None else params()
        if got is None:  # an asphere with power terms (odd or r^2): the numpy code solves it
            return None
        c, k, coef = got
        head = [1.0 if coef else 0.0, c, k, vtx.surface.front_sign(), 1.0 if vtx.reflect else 0.0,
                vtx.eta_front, vtx.eta_back, *np.asarray(vtx.surface.rotation, float).ravel(),
                *np.asarray(vtx.surface.vertex_mm, float), float(len(coef))]
        rows.append(head + [float(a) for a in coef])
    width = max(len(r) for r in rows)
    out = np.zeros((len(rows), width))
    for i, r in enumerate(rows):
        out[i, :len(r)] = r
    return out


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _surface_point(par, i, u, v, X, N, j):
    """X[j], N[j]: the world point and front unit normal of vertex i's surface at local (u, v)
    (specular_manifold.surface_points)."""
    c = par[i, C]
    kc = par[i, CONIC]
    rho = math.hypot(u, v)
    h = c * rho * rho / (1.0 + np.sqrt(1.0 - (1.0 + kc) * c * c * rho * rho))
    if par[i, KIND] == 1.0:
        rho2 = rho * rho
        s = 0.0
        for m in range(int(par[i, NCOEF])):
            s = s + par[i, COEF + m] * rho2 ** float(m + 2)
        h = h + s
        q2 = u * u + v * v
        q = c / np.sqrt(1.0 - (1.0 + kc) * c * c * q2)
        qp = 0.0
        for m in range(int(par[i, NCOEF])):
            qp = qp + (2 * m + 4) * par[i, COEF + m] * q2 ** float(m + 1)
        q = q + qp
        gx, gy, gz = q * u, q * v, -1.0
    else:
        gx, gy, gz = 2 * c * u, 2 * c * v, -2.0 + 2.0 * (1.0 + kc) * c * h
    sg = par[i, SIGN]
    gx, gy, gz = gx * sg, gy * sg, gz * sg
    gn = np.sqrt(gx * gx + gy * gy + gz * gz)
    gx, gy, gz = gx / gn, gy / gn, gz / gn
    for a in range(3):
        X[j, a] = u * par[i, ROT + a] + v * par[i, ROT + 3 + a] + h * par[i, ROT + 6 + a] + par[i, VERTEX + a]
        N[j, a] = gx * par[i, ROT + a] + gy * par[i, ROT + 3 + a] + gz * par[i, ROT + 6 + a]


@njit(cache=True, nogil=True, error_model="numpy")
def _points(par, k, x, X, N):
    for i in range(k):
        _surface_point(par, i, x[2 * i], x[2 * i + 1], X, N, i)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _constraint(par, k, i, X, N, p, z, F, off):
    """F[off], F[off + 1]: vertex i's tangents dotted with omega_a + omega_b (eta omega_a + omega_b)
    (specular_manifold._constraint)."""
    if i == 0:
        ax, ay, az = p[0] - X[i, 0], p[1] - X[i, 1], p[2] - X[i, 2]
    else:
        ax, ay, az = X[i - 1, 0] - X[i, 0], X[i - 1, 1] - X[i, 1], X[i - 1, 2] - X[i, 2]
    if i == k - 1:
        bx, by, bz = z[0] - X[i, 0], z[1] - X[i, 1], z[2] - X[i, 2]
    else:
        bx, by, bz = X[i + 1, 0] - X[i, 0], X[i + 1, 1] - X[i, 1], X[i + 1, 2] - X[i, 2]
    na = np.sqrt(ax * ax + ay * ay + az * az)
    nb = np.sqrt(bx * bx + by * by + bz * bz)
    na = na if na > 0 else 1.0
    nb = nb if nb > 0 else 1.0
    ax, ay, az = ax / na, ay / na, az / na
    bx, by, bz = bx / nb, by / nb, bz / nb
    eta = 1.0
    if par[i, REFLECT] == 0.0:
        eta = par[i, ETA_FRONT] if ax * N[i, 0] + ay * N[i, 1] + az * N[i, 2] > 0 else par[i, ETA_BACK]
    h0 = eta * ax + bx
    h1 = eta * ay + by
    h2 = eta * az + bz
    nh = N[i, 0] * h0 + N[i, 1] * h1 + N[i, 2] * h2
    for r in range(2):
        o = ROT + 3 * r
        F[off + r] = (h0 * par[i, o] + h1 * par[i, o + 1] + h2 * par[i, o + 2]
                      - (N[i, 0] * par[i, o] + N[i, 1] * par[i, o + 1] + N[i, 2] * par[i, o + 2]) * nh)


@njit(cache=True, nogil=True, error_model="numpy")
def _residual(par, k, x, p, z, X, N, F):
    _points(par, k, x, X, N)
    for i in range(k):
        _constraint(par, k, i, X, N, p, z, F, 2 * i)
    s = 0.0
    for r in range(2 * k):
        s += F[r] * F[r]
    return np.sqrt(s)


@njit(cache=True, nogil=True, error_model="numpy")
def _jacobian(par, k, x, p, z, X, N, F, central, diff, J, Fp, Fm, keep):
    """dF/dx (2k, 2k) into J at x (X, N its points; F = F(x) for forward differences): only the rows of
    the moved vertex and its neighbours (the others are exactly 0); specular_manifold._jacobian."""
    d = 2 * k
    for r in range(d):
        for c in range(d):
            J[r, c] = 0.0
    for c in range(d):
        i = c // 2
        for a in range(3):
            keep[0, a] = X[i, a]
            keep[1, a] = N[i, a]
        lo = max(i - 1, 0)
        hi = min(i + 1, k - 1)
        for sgn in range(2 if central else 1):
            step = diff if sgn == 0 else -diff
            u = x[2 * i] + (step if c % 2 == 0 else 0.0)
            v = x[2 * i + 1] + (step if c % 2 == 1 else 0.0)
            _surface_point(par, i, u, v, X, N, i)
            out = Fp if sgn == 0 else Fm
            for j in range(lo, hi + 1):
                _constraint(par, k, j, X, N, p, z, out, 2 * j)
        for r in range(2 * lo, 2 * hi + 2):
            if central:
                J[r, c] = (Fp[r] - Fm[r]) / (2 * diff)
            else:
                J[r, c] = (Fp[r] - F[r]) / diff
        for a in range(3):
            X[i, a] = keep[0, a]
            N[i, a] = keep[1, a]


@njit(cache=True, nogil=True, error_model="numpy")
def _lu_solve(J, b, A, out):
    """out = J^-1 b and det J by Gaussian elimination with partial pivoting (the first largest pivot, as
    LAPACK's getrf); J is left unchanged."""
    d = J.shape[0]
    for r in range(d):
        out[r] = b[r]
        for c in range(d):
            A[r, c] = J[r, c]
    det = 1.0
    for c in range(d):
        piv = c
        best = abs(A[c, c])
        for r in range(c + 1, d):
            if abs(A[r, c]) > best:
                best = abs(A[r, c])
                piv = r
        if piv != c:
            det = -det
            for cc in range(d):
                A[c, cc], A[piv, cc] = A[piv, cc], A[c, cc]
            out[c], out[piv] = out[piv], out[c]
        det *= A[c, c]
        if A[c, c] != 0.0:
            for r in range(c + 1, d):
                f = A[r, c] / A[c, c]
                A[r, c] = f
                for cc in range(c + 1, d):
                    A[r, cc] -= f * A[c, cc]
                out[r] -= f * out[c]
    for r in range(d - 1, -1, -1):
        s = out[r]
        for cc in range(r + 1, d):
            s -= A[r, cc] * out[cc]
        out[r] = s / A[r, r]
    return det


@njit(cache=True, nogil=True, error_model="numpy")
def solve_rows(par, p, z, x, active, newton_iter, give_up_after, give_up_residual, newton_tol, residual_tol,
               diff, X_out, N_out, ok_out):
    """Newton's method per row from x (m, 2k), in place (specular_manifold.solve_numpy, the same rules);
    rows with ``active`` False keep their x and fail. X_out, N_out (m, k, 3) the solved points (NaN where
    not ok), ok_out (m,)."""
    m = x.shape[0]
    k = par.shape[0]
    d = 2 * k
    X = np.empty((k, 3))
    N = np.empty((k, 3))
    F = np.empty(d)
    nF = np.empty(d)
    Fp = np.empty(d)
    Fm = np.empty(d)
    J = np.empty((d, d))
    A = np.empty((d, d))
    keep = np.empty((2, 3))
    step = np.empty(d)
    xr = np.empty(d)
    nx = np.empty(d)
    for row in range(m):
        for a in range(k):
            for b in range(3):
                X_out[row, a, b] = np.nan
                N_out[row, a, b] = np.nan
        ok_out[row] = False
        if not active[row]:
            continue
        pr = p[row]
        zr = z[row]
        for r in range(d):
            xr[r] = x[row, r]
        norm = _residual(par, k, xr, pr, zr, X, N, F)
        live = np.isfinite(norm)
        done = live and norm <= 1e-14
        for it in range(newton_iter):
            if not live or done:
                break
            # X, N hold the points at xr: the last residual evaluated was at the accepted step
            _jacobian(par, k, xr, pr, zr, X, N, F, False, diff, J, Fp, Fm, keep)
            finite = True
            for r in range(d):
                for c in range(d):
                    if not np.isfinite(J[r, c]):
                        finite = False
            det = _lu_solve(J, F, A, step) if finite else 0.0
            if not (finite and abs(det) > 1e-300):
                live = False
                break
            scale = 1.0
            for r in range(d):
                nx[r] = xr[r] + -step[r]
            new_norm = _residual(par, k, nx, pr, zr, X, N, nF)
            for _h in range(8):  # halve the step while the residual grows (or leaves the surface)
                if (new_norm <= norm) or not (norm > residual_tol):
                    break
                scale *= 0.5
                for r in range(d):
                    nx[r] = xr[r] + scale * -step[r]
                new_norm = _residual(par, k, nx, pr, zr, X, N, nF)
            moved = 0.0
            for r in range(d):
                moved = max(moved, abs(nx[r] - xr[r]))
                xr[r] = nx[r]
                F[r] = nF[r]
            norm = new_norm
            done = (moved <= newton_tol) or (new_norm <= 1e-14)
            live = live and np.isfinite(new_norm)
            if it >= give_up_after:  # not near a root by now: no solution from this start
                live = live and new_norm <= give_up_residual
        for r in range(d):
            x[row, r] = xr[r]
        if not (live and np.isfinite(norm) and norm <= residual_tol):
            continue
        _points(par, k, xr, X, N)
        good = True
        for a in range(k):
            for b in range(3):
                good = good and np.isfinite(X[a, b])
        if not good:
            continue
        ok_out[row] = True
        for a in range(k):
            for b in range(3):
                X_out[row, a, b] = X[a, b]
                N_out[row, a, b] = N[a, b]


@njit(cache=True, nogil=True, error_model="numpy")
def jacobians_rows(par, x, p, z, t, b, diff, diff_z, Jx, Jz, dX):
    """Per row: the central-difference dF/dx (2k, 2k), dF/dz along the tangents t, b (2k, 2) and dX_1/d(u_1, v_1)
    (3, 2) of specular_manifold.implicit_geometry_term (its numpy twin: implicit_jacobians_numpy)."""
    m = x.shape[0]
    k = par.shape[0]
    d = 2 * k
    X = np.empty((k, 3))
    N = np.empty((k, 3))
    Fp = np.empty(d)
    Fm = np.empty(d)
    keep = np.empty((2, 3))
    zs = np.empty(3)
    X1 = np.empty((2, 3))
    N1 = np.empty((2, 3))
    for row in range(m):
        xr = x[row]
        pr = p[row]
        _points(par, k, xr, X, N)
        _jacobian(par, k, xr, pr, z[row], X, N, Fp, True, diff, Jx[row], Fp, Fm, keep)
        for r in range(d):
            for c in range(2):
                Jz[row, r, c] = 0.0
        for c in range(2):
            e = t[row] if c == 0 else b[row]
            for a in range(3):
                zs[a] = z[row, a] + diff_z * e[a]
            _constraint(par, k, k - 1, X, N, pr, zs, Fp, 0)
            for a in range(3):
                zs[a] = z[row, a] - diff_z * e[a]
            _constraint(par, k, k - 1, X, N, pr, zs, Fm, 0)
            for r in range(2):
                Jz[row, d - 2 + r, c] = (Fp[r] - Fm[r]) / (2 * diff_z)
        for c in range(2):
            u0, v0 = xr[0], xr[1]
            _surface_point(par, 0, u0 + (diff if c == 0 else 0.0), v0 + (diff if c == 1 else 0.0), X1, N1, 0)
            _surface_point(par, 0, u0 - (diff if c == 0 else 0.0), v0 - (diff if c == 1 else 0.0), X1, N1, 1)
            for a in range(3):
                dX[row, a, c] = (X1[0, a] - X1[1, a]) / (2 * diff)


# ---------------------------------------------------------------------- shooting (the ghosts' solve)

@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _sag_slope(par, i, u, v):
    """(h, dh/du, dh/dv) of vertex i's surface at local (u, v) (the sag of :func:`_surface_point`)."""
    c = par[i, C]
    kc = par[i, CONIC]
    q2 = u * u + v * v
    root = np.sqrt(1.0 - (1.0 + kc) * c * c * q2)
    h = c * q2 / (1.0 + root)
    q = c / root
    if par[i, KIND] == 1.0:
        for m in range(int(par[i, NCOEF])):
            h = h + par[i, COEF + m] * q2 ** float(m + 2)
            q = q + (2 * m + 4) * par[i, COEF + m] * q2 ** float(m + 1)
    return h, q * u, q * v


@njit(cache=True, nogil=True, error_model="numpy")
def _meet(par, i, o, d, uv, max_iter, tol):
    """The local (u, v) (into ``uv``) where the ray o + t d (world) meets vertex i's surface, by Newton's method
    on w(t) - h(u(t), v(t)) from the vertex plane's crossing; False where it does not converge ahead of o."""
    ou = ov = ow = du = dv = dw = 0.0
    for a in range(3):
        rel = o[a] - par[i, VERTEX + a]
        ou += par[i, ROT + a] * rel
        ov += par[i, ROT + 3 + a] * rel
        ow += par[i, ROT + 6 + a] * rel
        du += par[i, ROT + a] * d[a]
        dv += par[i, ROT + 3 + a] * d[a]
        dw += par[i, ROT + 6 + a] * d[a]
    if dw == 0.0:
        return False
    t = -ow / dw
    c = par[i, C]
    if c != 0.0:  # the conic's quadric c (u^2 + v^2 + (1 + k) w^2) - 2 w = 0: its root on the vertex's branch
        kk = 1.0 + par[i, CONIC]
        qa = c * (du * du + dv * dv + kk * dw * dw)
        qb = 2.0 * c * (ou * du + ov * dv + kk * ow * dw) - 2.0 * dw
        qc = c * (ou * ou + ov * ov + kk * ow * ow) - 2.0 * ow
        disc = qb * qb - 4.0 * qa * qc
        if disc < 0.0:
            return False
        qq = -0.5 * (qb + math.copysign(np.sqrt(disc), qb))
        if qq == 0.0:
            return False
        t = qc / qq  # (the root that tends to the vertex plane's crossing as the curvature vanishes)
        if par[i, KIND] != 1.0:
            max_iter = 2  # exact: Newton below only confirms it
    for _ in range(max_iter):
        u = ou + t * du
        v = ov + t * dv
        h, hu, hv = _sag_slope(par, i, u, v)
        f = ow + t * dw - h
        df = dw - hu * du - hv * dv
        if not (df != 0.0 and np.isfinite(f)):
            return False
        step = f / df
        t -= step
        if abs(step) <= tol * (1.0 + abs(t)):
            uv[0] = ou + t * du
            uv[1] = ov + t * dv
            return t > 0.0 and np.isfinite(t)
    return False


@njit(cache=True, nogil=True, error_model="numpy")
def _shoot(par, k, p, s0, s1, e1, e2, nz, z, x, X, N, land, scratch):
    """Trace P -> vertex 0 at local (s0, s1) -> .. -> the plane through z of normal nz along the sequence
    (reflection or refraction by each vertex's law): x (2k) the vertices' local coordinates, X, N their points
    and front normals, land (2) the landing point's offset from z along e1, e2. False where a ray misses a
    surface or is totally reflected. ``scratch`` (3, 3): work space."""
    d = scratch[0]
    o = scratch[1]
    uv = scratch[2]
    x[0] = s0
    x[1] = s1
    _surface_point(par, 0, s0, s1, X, N, 0)
    norm = 0.0
    for a in range(3):
        d[a] = X[0, a] - p[a]
        norm += d[a] * d[a]
    norm = np.sqrt(norm)
    if not norm > 0.0:
        return False
    for a in range(3):
        d[a] /= norm
    for i in range(k):
        dn = d[0] * N[i, 0] + d[1] * N[i, 1] + d[2] * N[i, 2]
        if par[i, REFLECT] == 1.0:
            for a in range(3):
                d[a] = d[a] - 2.0 * dn * N[i, a]
        else:
            eta = par[i, ETA_FRONT] if dn < 0.0 else par[i, ETA_BACK]
            sgn = 1.0 if dn < 0.0 else -1.0  # n_in = sgn N faces the arriving light
            cos_i = -dn * sgn
            sin2 = eta * eta * (1.0 - cos_i * cos_i)
            if sin2 >= 1.0:
                return False
            cos_t = np.sqrt(1.0 - sin2)
            for a in range(3):
                d[a] = eta * d[a] + (eta * cos_i - cos_t) * sgn * N[i, a]
        norm = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        for a in range(3):
            d[a] /= norm
        if i == k - 1:
            break
        for a in range(3):
            o[a] = X[i, a]
        if not _meet(par, i + 1, o, d, uv, 30, 1e-12):
            return False
        x[2 * i + 2] = uv[0]
        x[2 * i + 3] = uv[1]
        _surface_point(par, i + 1, uv[0], uv[1], X, N, i + 1)
    dnz = d[0] * nz[0] + d[1] * nz[1] + d[2] * nz[2]
    if dnz == 0.0:
        return False
    t = ((z[0] - X[k - 1, 0]) * nz[0] + (z[1] - X[k - 1, 1]) * nz[1] + (z[2] - X[k - 1, 2]) * nz[2]) / dnz
    if not t > 0.0:
        return False
    l0 = l1 = 0.0
    for a in range(3):
        off = X[k - 1, a] + t * d[a] - z[a]
        l0 += off * e1[a]
        l1 += off * e2[a]
    land[0] = l0
    land[1] = l1
    return np.isfinite(l0) and np.isfinite(l1)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _counted(shots, row, par, k, p, s0, s1, e1, e2, nz, z, x, X, N, land, scratch):
    """:func:`_shoot`, counted in shots[row]."""
    shots[row] += 1
    return _shoot(par, k, p, s0, s1, e1, e2, nz, z, x, X, N, land, scratch)


@njit(cache=True, nogil=True, error_model="numpy")
def shoot_rows(par, p, z, nz, e1, e2, x, active, newton_iter, diff, land_tol, broyden, X_out, N_out, J_out, ok_out,
               shots_out):
    """Per row: Newton's method on the local (u, v) of the first vertex so that the traced path lands on z
    (:func:`_shoot`; a 2 x 2 forward-difference Jacobian of the landing point, step halving while it moves
    away), from x[row, :2]; x (m, 2k) gets the vertices' local coordinates. J_out: |d omega / dA_z| from the
    same Jacobian at the root (the solid angle of the directions at P over the area they land on); shots_out (m,)
    the traces each row took."""
    m = x.shape[0]
    k = par.shape[0]
    X = np.empty((k, 3))
    N = np.empty((k, 3))
    Xd = np.empty((k, 3))
    Nd = np.empty((k, 3))
    xr = np.empty(2 * k)
    xd = np.empty(2 * k)
    land = np.empty(2)
    ld = np.empty(2)
    jac = np.empty((2, 2))
    om = np.empty((3, 3))
    scratch = np.empty((3, 3))
    for row in range(m):
        ok_out[row] = False
        J_out[row] = 0.0
        shots_out[row] = 0
        for a in range(k):
            for b in range(3):
                X_out[row, a, b] = np.nan
                N_out[row, a, b] = np.nan
        if not active[row]:
            continue
        pr, zr, nr, ar, br = p[row], z[row], nz[row], e1[row], e2[row]
        s0, s1 = x[row, 0], x[row, 1]
        started = False
        # from the first surface's vertex (a ghost's two inner reflections fold its path: the straight line's
        # crossing is far from its root), else from x's start pulled toward the axis
        for pull in (0.0, 1.0, 0.5, 0.25):
            a0, a1 = (pull * s0, pull * s1) if pull > 0.0 else (0.0, 0.0)
            if _counted(shots_out, row, par, k, pr, a0, a1, ar, br, nr, zr, xr, X, N, land, scratch):
                s0, s1 = a0, a1
                started = True
                break
        if not started:
            continue
        err = np.hypot(land[0], land[1])
        good = False
        fresh = True  # the Jacobian is re-made by differences after a rejected secant step, else updated (Broyden)
        for _it in range(newton_iter):
            if err <= land_tol:
                good = True
                break
            fine = True
            if fresh:
                for c in range(2):
                    if not _counted(shots_out, row, par, k, pr, s0 + (diff if c == 0 else 0.0), s1 + (diff if c == 1 else 0.0), ar, br,
                                  nr, zr, xd, Xd, Nd, ld, scratch):
                        fine = False
                        break
                    jac[0, c] = (ld[0] - land[0]) / diff
                    jac[1, c] = (ld[1] - land[1]) / diff
            det = jac[0, 0] * jac[1, 1] - jac[0, 1] * jac[1, 0]
            if not (fine and det != 0.0 and np.isfinite(det)):
                break
            st0 = (jac[1, 1] * land[0] - jac[0, 1] * land[1]) / det
            st1 = (-jac[1, 0] * land[0] + jac[0, 0] * land[1]) / det
            scale = 1.0
            moved = False
            for _h in range(8):
                n0, n1 = s0 - scale * st0, s1 - scale * st1
                if _counted(shots_out, row, par, k, pr, n0, n1, ar, br, nr, zr, xd, Xd, Nd, ld, scratch) and np.hypot(ld[0], ld[1]) < err:
                    if broyden:  # the secant update: jac += (d_land - jac d_s) d_s^T / |d_s|^2
                        ds0, ds1 = n0 - s0, n1 - s1
                        dd = ds0 * ds0 + ds1 * ds1
                        r0 = ld[0] - land[0] - (jac[0, 0] * ds0 + jac[0, 1] * ds1)
                        r1 = ld[1] - land[1] - (jac[1, 0] * ds0 + jac[1, 1] * ds1)
                        jac[0, 0] += r0 * ds0 / dd
                        jac[0, 1] += r0 * ds1 / dd
                        jac[1, 0] += r1 * ds0 / dd
                        jac[1, 1] += r1 * ds1 / dd
                    fresh = not broyden or scale < 1.0
                    s0, s1 = n0, n1
                    err = np.hypot(ld[0], ld[1])
                    for r in range(2 * k):
                        xr[r] = xd[r]
                    for a in range(k):
                        for b in range(3):
                            X[a, b] = Xd[a, b]
                            N[a, b] = Nd[a, b]
                    land[0], land[1] = ld[0], ld[1]
                    moved = True
                    break
                scale *= 0.5
            if not moved:
                if fresh:
                    break
                fresh = True  # a secant Jacobian that found no descent: differences again from here
        if not good and err <= land_tol:
            good = True
        if not good:
            continue
        # |d omega / dA_z| at the root: the directions at P and the landing points of two nearby shots
        fine = True
        for c in range(3):
            if c > 0:
                if not _counted(shots_out, row, par, k, pr, s0 + (diff if c == 1 else 0.0), s1 + (diff if c == 2 else 0.0),
                                ar, br, nr, zr, xd, Xd, Nd, ld, scratch):
                    fine = False
                    break
                jac[0, c - 1] = (ld[0] - land[0]) / diff
                jac[1, c - 1] = (ld[1] - land[1]) / diff
            norm = 0.0
            for b in range(3):
                om[c, b] = (X[0, b] if c == 0 else Xd[0, b]) - pr[b]
                norm += om[c, b] * om[c, b]
            norm = np.sqrt(norm)
            for b in range(3):
                om[c, b] /= norm
        det = jac[0, 0] * jac[1, 1] - jac[0, 1] * jac[1, 0]
        if not (fine and det != 0.0):
            continue
        ax, ay, az = om[1, 0] - om[0, 0], om[1, 1] - om[0, 1], om[1, 2] - om[0, 2]
        bx, by, bz = om[2, 0] - om[0, 0], om[2, 1] - om[0, 1], om[2, 2] - om[0, 2]
        cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
        J_out[row] = np.sqrt(cx * cx + cy * cy + cz * cz) / (diff * diff) / abs(det)
        ok_out[row] = np.isfinite(J_out[row]) and J_out[row] > 0.0
        for r in range(2 * k):
            x[row, r] = xr[r]
        for a in range(k):
            for b in range(3):
                X_out[row, a, b] = X[a, b]
                N_out[row, a, b] = N[a, b]
