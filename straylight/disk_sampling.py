"""Uniform points on an exact disk or annulus (an analytic ``plane`` detector, CONTRACTS §6.4).

``rho = sqrt(inner^2 + u_b (outer^2 - inner^2))``, ``phi = 2 pi u_c``: the inverse of the radial
cdf (rho^2 - inner^2) / (outer^2 - inner^2) of a uniform annulus, so the pdf per unit area is
1 / (pi (outer^2 - inner^2)) (e.g. Pharr, Jakob & Humphreys, *PBRT* 4th ed., §A.5.1). One compiled
function serves the next-event kernel, its numpy twin and :class:`straylight.detectors.DetectorGeometry`,
so all three draw the same bits."""
from __future__ import annotations

import math

import numpy as np

from materials.jit_cache import njit

TWO_PI = 2.0 * math.pi


@njit(cache=True, nogil=True)
def annulus_point(centre, u_axis, v_axis, r2_in, r2_out, ub, uc):
    """(x, y, z) of the point of uniforms (ub, uc) on the annulus about ``centre`` in the plane (u, v)."""
    rho = math.sqrt(r2_in + ub * (r2_out - r2_in))
    phi = TWO_PI * uc
    a = rho * math.cos(phi)
    b = rho * math.sin(phi)
    return ((centre[0] + a * u_axis[0]) + b * v_axis[0], (centre[1] + a * u_axis[1]) + b * v_axis[1],
            (centre[2] + a * u_axis[2]) + b * v_axis[2])


@njit(cache=True, nogil=True)
def annulus_points(centre, u_axis, v_axis, r2_in, r2_out, ub, uc, out):
    """:func:`annulus_point` for arrays ``ub``, ``uc`` (n,) into ``out`` (n, 3)."""
    for i in range(len(ub)):
        out[i, 0], out[i, 1], out[i, 2] = annulus_point(centre, u_axis, v_axis, r2_in, r2_out, ub[i], uc[i])
    return out


def sample_annulus(disk, ub, uc) -> np.ndarray:
    """(n, 3) uniform points on ``disk`` (a :class:`straylight.detectors.Disk`)."""
    ub = np.ascontiguousarray(ub, dtype=np.float64)
    uc = np.ascontiguousarray(uc, dtype=np.float64)
    return annulus_points(disk.centre_mm, disk.u_axis, disk.v_axis, disk.r2_in, disk.r2_out, ub, uc,
                          np.empty((len(ub), 3)))
