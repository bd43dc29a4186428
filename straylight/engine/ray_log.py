"""Stage: the ray log. Every segment of the first ``OutputOptions.ray_log`` rays of a trace, as the
walk moved them: the rays the pictures and the 3-D view draw (straylight.viz.trace_ray_paths), so
the drawing follows the engine's own physics (refraction, mirrors, diffraction, any optics).

One row per segment a logged ray travels: from ``origin_mm`` along ``direction`` to ``end_mm``,
the triangle it ends on (:data:`SEGMENT_ESCAPE` for a ray that leaves the scene: its end is its
origin, the direction says where it went; :data:`SEGMENT_BEND` for a ray bent at a diffracting edge
before its hit: its end is the bend), the power it carries (``weight_w``) and whether it ends on a
detector part. Rows are sorted by (ray, event): deterministic whatever the batches or workers.
Logging is Python at the walk level, on the rays with an id below the limit; with ``ray_log = 0``
nothing is made or called."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from straylight.engine.roles import ROLE_DETECTOR

SEGMENT_ESCAPE = -1  # ``tri`` of a segment that leaves the scene
SEGMENT_BEND = -2  # ``tri`` of a segment that ends at a bend at a diffracting edge

FIELDS = ("ray", "event", "origin_mm", "direction", "end_mm", "tri", "kind", "weight_w", "detector")


@dataclass(frozen=True, eq=False)
class RayLog:
    """The logged segments (:mod:`straylight.engine.ray_log`), one row each, sorted by (ray, event)."""

    ray: np.ndarray  # (m,) int64 ray id in the trace (0 .. ray_log - 1)
    event: np.ndarray  # (m,) int64 event index of the segment (0: it leaves the source)
    origin_mm: np.ndarray  # (m, 3) start of the segment
    direction: np.ndarray  # (m, 3) unit direction
    end_mm: np.ndarray  # (m, 3) hit point (on an exact surface where the part has one); the bend for
    # SEGMENT_BEND; the origin for SEGMENT_ESCAPE
    tri: np.ndarray  # (m,) int64 triangle hit, SEGMENT_ESCAPE or SEGMENT_BEND
    kind: np.ndarray  # (m,) int8 the event the segment leaves (straylight.engine.ray_batch EVENT_*: 0 source,
    # 1 scatter, 2 specular: a mirror, an interface's reflection or refraction, 3 a bend at an edge)
    weight_w: np.ndarray  # (m,) power the ray carries on the segment, W
    detector: np.ndarray  # (m,) bool: the segment ends on a detector part

    def __len__(self) -> int:
        return len(self.ray)

    def rays(self) -> list[tuple[int, slice]]:
        """(ray id, its rows) for each logged ray, ascending id."""
        if len(self.ray) == 0:
            return []
        ids, start = np.unique(self.ray, return_index=True)
        stop = np.append(start[1:], len(self.ray))
        return [(int(i), slice(int(a), int(b))) for i, a, b in zip(ids, start, stop)]

    @classmethod
    def concatenate(cls, pieces) -> "RayLog":
        """One log of the batches' pieces (dicts of :data:`FIELDS`, None for a batch without logged rays)."""
        pieces = [p for p in pieces if p is not None]
        if not pieces:
            return cls(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)),
                       np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0, np.int8), np.zeros(0), np.zeros(0, bool))
        cols = {f: np.concatenate([p[f] for p in pieces]) for f in FIELDS}
        order = np.lexsort((cols["event"], cols["ray"]))
        return cls(**{f: cols[f][order] for f in FIELDS})


def _on_exact_surfaces(spec, rays, hit, sel, on, end) -> None:
    """``end[on]`` (rows ``sel[on]`` of the event, which met a part) moved onto the parts' exact surfaces
    where the hit refines there (straylight.engine.surface_geometry.refine_on_surfaces, as the interaction)."""
    from straylight.engine.surface_geometry import refine_on_surfaces

    if len(on) == 0:
        return
    rows = sel[on]
    _, _, exact, refined, passing = refine_on_surfaces(
        spec, hit.part[rows].astype(np.int64), rays.origin_mm[rows], rays.direction[rows], hit.distance_mm[rows],
        rays.last_part[rows], hit.cos_in[rows] < 0, hit.facing_normal[rows].copy())
    ok = refined & ~passing
    end[on[ok]] = exact[ok]


class RayLogger:
    """Collects the segments of one batch's rays with a batch index below ``limit`` (ray ids
    ``first_ray + index`` in the trace)."""

    def __init__(self, limit: int, first_ray: int, part_roles):
        self.limit = int(limit)
        self.first_ray = int(first_ray)
        self.part_roles = np.asarray(part_roles)
        self.rows: list[tuple] = []

    def _add(self, ev, rays, rows, end, tri, detector):
        self.rows.append((rays.ray[rows].astype(np.int64) + self.first_ray, np.full(len(rows), ev, dtype=np.int64),
                          rays.origin_mm[rows], rays.direction[rows], end, tri.astype(np.int64),
                          rays.last_event[rows].astype(np.int8), rays.weight_w[rows], detector))

    def segments(self, ev: int, rays, tri, hit, triangle_part, spec=None) -> None:
        """Event ``ev``'s segments of the logged rays among ``rays`` (``tri``: triangle hit, -1: escape;
        ``hit``: straylight.engine.hits.Hits). A hit on a part with an exact surface (``spec``'s
        ``part_surfaces``: lenses, mirrors) ends on that surface, where the interaction takes it, not on
        the facet (up to the mesh's sagitta away); a hit that passes outside the clear aperture keeps the
        facet's point."""
        sel = np.flatnonzero(rays.ray < self.limit)
        if len(sel) == 0:
            return
        t = np.asarray(tri)[sel]
        escaped = t < 0
        origin = rays.origin_mm[sel]
        end = np.where(escaped[:, None], origin, hit.point_mm[sel])
        if spec is not None and spec.part_surfaces:
            _on_exact_surfaces(spec, rays, hit, sel, np.flatnonzero(~escaped), end)
        part = triangle_part[np.maximum(t, 0)]
        detector = ~escaped & (self.part_roles[part] == ROLE_DETECTOR)
        self._add(ev, rays, sel, end, np.where(escaped, SEGMENT_ESCAPE, t), detector)

    def bends(self, ev: int, rays, keep, bent) -> None:
        """Event ``ev``'s segments that end at a diffracting edge: ``rays`` before the split, ``keep``
        the rows that go on to their hit, ``bent`` the bent rays' next state (straylight.engine.diffraction.divert)."""
        rows = np.setdiff1d(np.arange(len(rays.ray)), keep)  # ascending, as divert lists the bent rays
        sel = np.flatnonzero(rays.ray[rows] < self.limit)
        if len(sel) == 0:
            return
        r = rows[sel]
        self._add(ev, rays, r, bent.origin_mm[sel], np.full(len(r), SEGMENT_BEND), np.zeros(len(r), bool))

    def piece(self) -> dict | None:
        """The batch's segments as a dict of :data:`FIELDS` arrays (None if none)."""
        if not self.rows:
            return None
        return {f: np.concatenate(col) for f, col in zip(FIELDS, zip(*self.rows))}
