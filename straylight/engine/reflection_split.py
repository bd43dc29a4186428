"""Reflections into a detector, counted by their expected value (the optics path).

At a Fresnel or specular interface (``optical_surface`` parts) the walk picks one branch, scatter
lobe, reflection or transmission, with probabilities proportional to their powers, and the chosen
ray carries the whole weight (docs/engine.md, "Branch by probability, not splitting"). A path
"... -> interface (reflection) -> detector" is then found only by the rays that pick the reflection
(an uncoated lens face: ~4 %), each with ~25x the weight the reflection actually carries. On the
guide scope (benchmarks/guide_scope.py) at 5 deg such paths, light scattered up by a vane behind
the lens and reflected by the lens's flat back face onto the 3 mm sensor, held 99.9 % of the
variance: a couple of rays in 1e5.

With ``EstimatorOptions(reflection_split=True)`` every interface hit where the reflection has power
casts the reflected ray once more (same direction, from the refined point); when its first hit is
a detector (on a counted side), the reflection's expected contribution

    w x E_r x bulk

(E_r the reflected fraction for this ray's polarization state, bulk the medium's attenuation on
the way in: exactly the expectation of the walk's reflect-branch hit) goes to that detector, and
the walk's own detector hits straight after a reflection there are dropped (moved to the NEE-exchange
row of the interface's part, :class:`ReflectionSplit`): the two are a partition of the same paths by
their expected value (a conditional expectation over the branch choice), so the sum is unbiased and
the branch's noise leaves those paths. Cost: one cast per interface hit that reflects anything.
"""
from __future__ import annotations

import numpy as np

from materials.smooth import reflect
from straylight.engine.ray_batch import EVENT_DETECTOR, EVENT_SPECULAR
from straylight.engine.roles import ROLE_DETECTOR
from straylight.engine.walk_shares import keep_walk_share
from straylight.paths import mix_key


class ReflectionSplit:
    """Per batch: for each ray, the depth of the hit that follows a reflection whose detector
    contribution was already counted by expectation (-1: none)."""

    def __init__(self, n_rays_in_batch):
        self.at_depth = np.full(n_rays_in_batch, -1, dtype=np.int64)

    def at_interfaces(self, event, h):
        """The interface hits ``h`` (straylight.engine.event.Interfaces) whose reflection has power:
        :meth:`connect` them from their (refined) points."""
        can = np.flatnonzero(h.live & (h.E_r > 0) & ~event.claimed(h.rows))  # reverse chains count those
        if len(can):
            rows = h.rows[can]
            at = np.where(h.refined[can, None], h.exact[can], event.hits.point_mm[rows])
            bulk = h.fresnel[6]
            self.connect(event, rows, at, h.facing[can], reflect(h.d[can], h.facing[can]),
                         event.rays.weight_w[rows] * h.E_r[can] * bulk[can], h.reflected[can])

    def connect(self, event, rows, point, facing, d_reflected, reflected_w, took_reflection):
        """Count the reflections of the interface hits ``rows`` (rows of the event) that go straight
        into a detector: ``point`` (on the surface), ``facing`` (normal on the incident side),
        ``d_reflected`` (unit), ``reflected_w`` (the ray's weight x E_r x bulk); remember the rays
        whose walk took the reflection branch (``took_reflection``), whose next detector hit is dropped."""
        rays = event.rays
        taken = rows[took_reflection]
        self.at_depth[rays.ray[taken]] = rays.depth[taken] + 1
        go = np.flatnonzero(reflected_w > 0)
        if len(go) == 0:
            return
        spec, scene = event.spec, event.scene
        origin = np.ascontiguousarray(point[go] + 2.0 * spec.eps * facing[go])
        d = np.ascontiguousarray(d_reflected[go])
        tri, dist = scene.isect.intersect(origin, d)
        event.shadow_rays += len(go)
        tri, dist = np.asarray(tri), np.asarray(dist, dtype=np.float64)
        hit = np.flatnonzero(tri >= 0)
        part = spec.triangle_part[tri[hit]].astype(np.int64)
        on = spec.part_roles[part] == ROLE_DETECTOR
        hit, part = hit[on], part[on]
        if not event.settings.both_sides:  # a front-only detector counts light against its normals
            front = np.einsum("ij,ij->i", d[hit], scene.normals[tri[hit]]) < 0
            hit, part = hit[front], part[front]
        if len(hit) == 0:
            return
        i = rows[go[hit]]
        c = reflected_w[go[hit]]
        j_of = scene.arrays.detector_of_part[part]
        r = rays.ray[i]
        code = event.hits.part[i].astype(np.int64) * 4 + EVENT_SPECULAR
        z = origin[hit] + dist[hit, None] * d[hit]
        for j in np.unique(j_of):
            m = np.flatnonzero(j_of == j)
            event.tallies.add(event.rows.detector_nee + int(j), r[m], c[m])
            event.tallies.subtract(event.rows.nee_exchange + event.hits.part[i[m]].astype(np.int64), r[m], c[m])
            _record(event, int(j), i[m], code[m], z[m], c[m])

    def share_after_reflection(self, event, rec, rec_w):
        """The walk's detector hits straight after a reflection counted by :meth:`connect` are dropped
        (their weight to the NEE exchange: the ledger stays exact)."""
        rays = event.rays
        after = np.flatnonzero((rays.last_event[rec] == EVENT_SPECULAR) & (self.at_depth[rays.ray[rec]] == rays.depth[rec]))
        if len(after) == 0:
            return rec, rec_w
        return keep_walk_share(event, rec, rec_w, after, np.zeros(len(after)))


def _record(event, j, i, code, z, c):
    """Map (and path) records of the reflections counted into detector j (rows ``i`` of the event)."""
    rays = event.rays
    keys = events = None
    depth = rays.depth[i]
    if event.settings.record_paths:
        keys = mix_key(mix_key(rays.path_key[i], code), event.scene.det_parts[j] * 4 + EVENT_DETECTOR)
        events = rays.history[i]
        inside = np.flatnonzero(depth < events.shape[1])
        events[inside, depth[inside]] = code[inside]
    event.records.add(j, rays.ray[i], z, c, keys, events, depth + 1)
