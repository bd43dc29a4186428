"""One row of an interface hit, for the compiled passes of the split trees (straylight.engine.delta_chain)
and the eye chains (straylight.engine.reverse_chain): the s vector of the plane of incidence, the rotation
of a Stokes vector's frame onto it, and the reflected or refracted direction. Each is the arithmetic of its
numpy function (materials.mueller's ``s_vector`` and ``rotate_stokes``, materials.smooth's ``reflect`` and
``refract``) in the same order, so the passes that inline them give those functions' bits (their tests
compare every field)."""
from __future__ import annotations

import math

from materials.jit_cache import njit


@njit(cache=True, nogil=True, inline="always")
def unit_s_vector(d0, d1, d2, n0, n1, n2):
    """s = d x n / |d x n|; where d is along n, d x (1, 0, 0), or d x (0, 1, 0) when that vanishes too
    (materials.mueller.s_vector)."""
    s0, s1, s2 = d1 * n2 - d2 * n1, d2 * n0 - d0 * n2, d0 * n1 - d1 * n0
    norm = math.sqrt((s0 * s0 + s1 * s1) + s2 * s2)
    if norm < 1e-12:
        s0, s1, s2 = d1 * 0.0 - d2 * 0.0, d2 * 1.0 - d0 * 0.0, d0 * 0.0 - d1 * 1.0
        norm = math.sqrt((s0 * s0 + s1 * s1) + s2 * s2)
        if norm < 1e-6:
            s0, s1, s2 = d1 * 0.0 - d2 * 1.0, d2 * 0.0 - d0 * 0.0, d0 * 1.0 - d1 * 0.0
            norm = math.sqrt((s0 * s0 + s1 * s1) + s2 * s2)
    return s0 / norm, s1 / norm, s2 / norm


@njit(cache=True, nogil=True, inline="always")
def frame_rotation(a0, a1, a2, m0, m1, m2, b0, b1, b2):
    """(cos 2 psi, sin 2 psi) of the rotation taking the Stokes frame of s vector a onto s vector b about
    the direction m (materials.mueller.rotate_stokes): S1' = c S1 + s S2, S2' = -s S1 + c S2."""
    cos_psi = (a0 * b0 + a2 * b2) + a1 * b1
    c0, c1, c2 = m1 * a2 - m2 * a1, m2 * a0 - m0 * a2, m0 * a1 - m1 * a0
    sin_psi = (c0 * b0 + c2 * b2) + c1 * b1
    return cos_psi * cos_psi - sin_psi * sin_psi, 2.0 * cos_psi * sin_psi


@njit(cache=True, nogil=True, inline="always")
def deflected(d0, d1, d2, f0, f1, f2, reflect, eta, cos_t):
    """The direction d leaves a smooth interface with (facing normal f) in: reflected (d - 2 (d.f) f,
    materials.smooth.reflect) or refracted (eta d + (eta cos_i - cos_t) f, normalised;
    materials.smooth.refract)."""
    if reflect:
        two_dot = 2.0 * ((d0 * f0 + d2 * f2) + d1 * f1)
        return d0 - two_dot * f0, d1 - two_dot * f1, d2 - two_dot * f2
    cos_i = -((d0 * f0 + d2 * f2) + d1 * f1)
    kk = eta * cos_i - cos_t
    t0, t1, t2 = eta * d0 + kk * f0, eta * d1 + kk * f1, eta * d2 + kk * f2
    norm = math.sqrt((t0 * t0 + t1 * t1) + t2 * t2)
    return t0 / norm, t1 / norm, t2 / norm
