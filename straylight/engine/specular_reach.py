"""Which side of an analytic surface a point can be on, seen from anywhere on the surface's clear
aperture: the cheap test specular next-event estimation (straylight.engine.specular_nee) runs before
its Newton solves, so that vertices and detectors on the wrong side of a lens face cost nothing.

A connection through a surface whose one side is glass leaves the scatter point P in the air and
reaches the detector point z in the air: P must lie strictly on the air side of the tangent plane at
the first interface point X_1 (``(P - X_1) . n > 0`` for the front), z on the air side of the tangent
plane at the last one (straylight.engine.specular_manifold.side_checks and media_agree refuse every
other path). This module answers, without solving, "no point of the aperture has Q on that side".

For a conic of revolution (geometry.analytic.Conic, Plane) in its local frame, X = (x, y, h(rho)) with
front normal n proportional to (-h'(rho) x / rho, -h'(rho) y / rho, 1) (n_3 > 0 on the sheet through
the vertex; h'(rho) = c rho / sqrt(1 - (1 + k) c^2 rho^2)). For Q = (q, q_3) local, |q| its distance from
the axis:

    (Q - X) . n / n_3 = q_3 - h(rho) + (q - x) . n_xy / n_3,   |n_xy / n_3| = |h'(rho)|,

and h and |h'| are monotone in rho for a conic, so over the aperture's rho in [rho_lo, rho_hi]
(s = |h'(rho_hi)|, h_lo, h_hi the least and largest sag):

    Q is never in front of any tangent plane when  q_3 - h_lo + (|q| + rho_hi) s <= 0,
    Q is never behind any tangent plane when       q_3 - h_hi - (|q| + rho_hi) s >= 0.

For every Q within a distance r of a point the same holds with q_3 +- r and |q| + r (a detector's
bounding ball: a sequence that cannot reach any of its points is skipped for that detector).

The test only refuses rows the exact checks would refuse (a margin of 1e-8 of the lengths involved
keeps round-off on the safe side), so the estimator's numbers do not change. Aspheres (whose sag need
not be monotone) and the other surfaces are not tested: every row may reach them.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from geometry.analytic import Conic, Plane

MARGIN = 1e-8  # of the lengths in the bound, mm per mm: round-off never refuses a row the checks keep


class SideTest(NamedTuple):
    """The sag range, the steepest slope and the largest distance from the axis over one surface's
    clear aperture (with its tolerance)."""

    surface: Conic
    h_lo: float
    h_hi: float
    slope: float
    rho_hi: float


def side_test(surface) -> SideTest | None:
    """The :class:`SideTest` of a conic or plane surface, None for any other (an asphere, a cylinder),
    where the aperture reaches past the conic's own extent or where its local frame is not orthonormal."""
    if type(surface) not in (Conic, Plane):
        return None
    rot = np.asarray(surface.rotation, dtype=np.float64)
    if not np.allclose(rot @ rot.T, np.eye(3), rtol=0.0, atol=1e-12):  # a frame built on a non-unit axis
        return None
    lo, hi = surface.rho_range_mm()
    tol = 2e-9 * max(1.0, float(surface.outer_radius_mm))  # Conic.in_aperture's tolerance, and some
    lo, hi = max(0.0, float(lo) - tol), float(hi) + tol
    c, k = surface.c, surface.conic
    root = 1.0 - (1.0 + k) * c * c * hi * hi
    if not root > 0.0:
        return None
    h = surface.sag(np.array([lo, hi]))
    return SideTest(surface, float(h.min()), float(h.max()), abs(c) * hi / math.sqrt(root), hi)


def may_lie(test: SideTest, front: bool, points, radius_mm: float = 0.0) -> np.ndarray:
    """(n,) bool: False where no point within ``radius_mm`` of ``points`` (n, 3) lies strictly on the
    ``front`` (else back) side of the tangent plane at any point of the surface's aperture (module
    doc); True where one may."""
    loc = test.surface.to_local(points)
    q3 = loc[:, 2]
    q = np.hypot(loc[:, 0], loc[:, 1]) + radius_mm
    reach = (q + test.rho_hi) * test.slope
    margin = MARGIN * (1.0 + np.abs(q3) + radius_mm + q + test.rho_hi + abs(test.h_lo) + abs(test.h_hi) + reach)
    if front:
        return q3 + radius_mm - test.h_lo + reach > -margin
    return q3 - radius_mm - test.h_hi - reach < margin


def air_side(vertex) -> bool | None:
    """The side of a sequence's vertex (straylight.engine.specular_manifold.Vertex) that is air when the
    other is not: True front, False back; None when both are (a mirror) or neither."""
    front, back = vertex.medium_front == -1, vertex.medium_back == -1
    return front if front != back else None


def aperture_ball(test: SideTest) -> tuple:
    """(centre (3,), radius) of a ball holding the surface's clear aperture: the aperture's disk about its
    centre, between the least and the largest sag."""
    surf = test.surface
    cu, cv = surf.aperture_center_uv
    centre = surf.to_world(np.array([[cu, cv, 0.5 * (test.h_lo + test.h_hi)]]))[0]
    outer = float(surf.outer_radius_mm) * (1.0 + 2e-9) + 2e-9
    radius = math.hypot(outer, 0.5 * (test.h_hi - test.h_lo))
    return centre, radius * (1.0 + 1e-9) + 1e-9


def may_face(points, normals, centre, radius_mm: float) -> np.ndarray:
    """(n,) bool: False where the ball (``centre``, ``radius_mm``) lies wholly behind the tangent plane of
    ``points`` (n, 3) with normals ``normals`` (n, 3): light leaving such a point on its normal's side
    cannot reach any point of it."""
    rel = centre[None, :] - points
    ahead = np.einsum("ij,ij->i", rel, normals) + radius_mm * np.linalg.norm(normals, axis=1)
    margin = MARGIN * (1.0 + np.linalg.norm(rel, axis=1) + radius_mm)
    return ahead > -margin
