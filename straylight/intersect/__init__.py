"""Ray-triangle intersection: :class:`EmbreeIntersector` (fast) and
:class:`ReferenceIntersector` (numpy, exact, slow) with the same interface.

``intersect(origins, dirs) -> (tri, t)``: index of the first triangle hit (-1 = miss) and the
distance along the unit direction (inf on a miss), float64, recomputed from the triangle's plane.
``occluded(origins, dirs, tmax) -> bool``: is there any hit with ``0 < t < tmax``.
``intersect_triangles(origins, dirs) -> tri`` (optional; embree and the exact-boundary wrapper have it):
the triangles of ``intersect`` without the distances, for callers that compute the distance from
the facet's plane themselves (straylight.engine.surface_geometry.cast_branches).
"""
from typing import Protocol

import numpy as np

from straylight.intersect.embree import EmbreeIntersector  # noqa: F401
from straylight.intersect.reference import ReferenceIntersector  # noqa: F401


class Intersector(Protocol):
    """What the tracers ask of an intersector (the module doc)."""

    def intersect(self, origins: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...

    def occluded(self, origins: np.ndarray, dirs: np.ndarray, tmax: np.ndarray) -> np.ndarray: ...
