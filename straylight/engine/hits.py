"""Stage: what each ray hit. After the ray casts (first triangle per ray), one pass per ray:
escape, the hit point and incident-side normal, the incident / first-hit tallies, and the
terminal interactions: detection (with its MIS share against NEE) and absorption. The rays that
go on (surface and mirror hits) are handed to their surface interactions
(straylight.engine.interactions). :func:`hits_numpy` is the numpy twin (same bits)."""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from materials.jit_cache import njit

from straylight.engine.ray_batch import EVENT_DIFFRACTION, EVENT_SCATTER
from straylight.engine.roles import ROLE_ABSORBER, ROLE_DETECTOR
from straylight.engine.tally_store import tally_add
from straylight.engine.vec3 import dot3, dot_rows, power_heuristic, power_heuristic_rows


class Hits(NamedTuple):
    """This event's hits, one row per live ray (rows of escaped rays are unused)."""

    continuing: np.ndarray  # rows of the rays that go on (surface or mirror hit), ascending
    point_mm: np.ndarray  # (n, 3) hit points
    facing_normal: np.ndarray  # (n, 3) geometric normal turned toward the incoming ray
    part: np.ndarray  # (n,) int64 part hit, -1 for an escape
    distance_mm: np.ndarray  # (n,) hit distance (float64, from the triangle's plane)
    cos_in: np.ndarray  # (n,) direction . geometric normal (< 0: the ray arrives on the front)
    detected: np.ndarray  # rows of counted detector hits
    detected_w: np.ndarray  # their weights (the MIS share of NEE removed)


HITS_WRITES_PER_RAY = 5  # most tally writes one ray makes in :func:`hits` (incident, first hit, 3 at a detector)


@njit(cache=True, nogil=True)
def hits(tri, rays, scene, rows, settings, log):
    """One pass over the live rays after the casts (``tri``: triangle hit, -1 = miss); tallies into
    ``log`` (straylight.engine.tally_store) at the rows of :class:`TallyRows`; returns the fields of
    :class:`Hits`."""
    n = len(tri)
    p = np.empty((n, 3))
    nf = np.empty((n, 3))
    part = np.empty(n, np.int64)
    t_out = np.empty(n)
    cos_out = np.empty(n)
    cont = np.empty(n, np.int64)
    rec = np.empty(n, np.int64)
    rec_w = np.empty(n)
    nc = 0
    nr = 0
    o, d, w = rays.origin_mm, rays.direction, rays.weight_w
    normals = scene.normals
    for i in range(n):
        k = tri[i]
        r = rays.ray[i]
        if k < 0:
            tally_add(log, rows.escaped, r, w[i])
            part[i] = -1
            continue
        pt = np.int64(scene.triangle_part[k])
        part[i] = pt
        role = scene.part_roles[pt]
        n0, n1, n2 = normals[k, 0], normals[k, 1], normals[k, 2]
        d0, d1, d2 = d[i, 0], d[i, 1], d[i, 2]
        o0, o1, o2 = o[i, 0], o[i, 1], o[i, 2]
        cos_in = dot3(d0, d1, d2, n0, n1, n2)
        # hit distance in float64 from the triangle's plane (embree found the triangle in float32)
        if abs(cos_in) < 1e-12:
            c = scene.centroids
            t = dot3(c[k, 0] - o0, c[k, 1] - o1, c[k, 2] - o2, d0, d1, d2)
        else:
            t = (scene.plane_d[k] - dot3(n0, n1, n2, o0, o1, o2)) / cos_in
        t_out[i] = t
        cos_out[i] = cos_in
        tc = t if (t > 0.0 or t != t) else 0.0  # np.maximum(t, 0): NaN propagates
        p[i, 0] = o0 + tc * d0
        p[i, 1] = o1 + tc * d1
        p[i, 2] = o2 + tc * d2
        if cos_in < 0:
            nf[i, 0], nf[i, 1], nf[i, 2] = n0, n1, n2
        else:
            nf[i, 0], nf[i, 1], nf[i, 2] = -n0, -n1, -n2
        w_i = w[i]
        tally_add(log, rows.incident + pt, r, w_i)
        if rays.last_event[i] == 0:
            tally_add(log, rows.first_hit + pt, r, w_i)
        if role == ROLE_DETECTOR:
            if not (settings.both_sides or cos_in < 0):
                tally_add(log, rows.absorbed + pt, r, w_i)
                continue
            j = scene.detector_of_part[pt]
            tally_add(log, rows.detector_walk + j, r, w_i)
            w_det = w_i
            # a hit straight after a scatter that did NEE is shared with NEE by MIS weights (power heuristic)
            # (or right after a bend at a diffracting edge, whose NEE straylight.engine.diffraction makes:
            # the bend's density is its last_pdf, > 0 where the HURB law has one)
            if settings.nee and ((rays.last_event[i] == EVENT_SCATTER and settings.nee_part[rays.last_part[i]])
                                 or (rays.last_event[i] == EVENT_DIFFRACTION and rays.last_pdf_per_sr[i] > 0)):
                p_nee = settings.nee_samples * (t * t) / (scene.detector_area_mm2[j] * abs(cos_in))
                w_det = w_i * power_heuristic(rays.last_pdf_per_sr[i], p_nee)
                tally_add(log, rows.nee_exchange + rays.last_part[i], r, w_i - w_det)
            if w_det > 0:
                tally_add(log, rows.detector_direct + j, r, w_det)
                rec[nr] = i
                rec_w[nr] = w_det
                nr += 1
        elif role == ROLE_ABSORBER:
            tally_add(log, rows.absorbed + pt, r, w_i)
        else:
            cont[nc] = i
            nc += 1
    return cont[:nc], p, nf, part, t_out, cos_out, rec[:nr], rec_w[:nr]


def hits_numpy(tri, rays, scene, rows, settings, M):
    """:func:`hits` in vectorised numpy (the reference)."""
    n = len(tri)
    tri = np.asarray(tri, dtype=np.int64)
    r = rays.ray
    w = rays.weight_w
    miss = tri < 0
    M[rows.escaped, r[miss]] += w[miss]
    part = np.full(n, -1, dtype=np.int64)
    part[~miss] = scene.triangle_part[tri[~miss]]
    k = np.where(miss, 0, tri)
    ng = scene.normals[k]
    o, d = rays.origin_mm, rays.direction
    cos_in = dot_rows(d, ng)
    edge_on = np.abs(cos_in) < 1e-12
    t = (scene.plane_d[k] - dot_rows(ng, o)) / np.where(edge_on, 1.0, cos_in)
    if edge_on.any():
        t[edge_on] = dot_rows(scene.centroids[k[edge_on]] - o[edge_on], d[edge_on])
    tc = np.maximum(t, 0.0)
    p = o + tc[:, None] * d
    nf = np.where((cos_in < 0)[:, None], ng, -ng)
    hit = np.flatnonzero(~miss)
    role = np.where(miss, -1, scene.part_roles[np.maximum(part, 0)])
    M[rows.incident + part[hit], r[hit]] += w[hit]
    first = hit[rays.last_event[hit] == 0]
    M[rows.first_hit + part[first], r[first]] += w[first]
    det = role == ROLE_DETECTOR
    sens = det & (settings.both_sides | (cos_in < 0))
    dead = np.flatnonzero(det & ~sens)
    M[rows.absorbed + part[dead], r[dead]] += w[dead]
    sens = np.flatnonzero(sens)
    j = scene.detector_of_part[part[sens]]
    M[rows.detector_walk + j, r[sens]] += w[sens]
    w_det = w[sens].copy()
    if settings.nee:
        shared = np.flatnonzero(((rays.last_event[sens] == EVENT_SCATTER)
                                 & settings.nee_part[np.maximum(rays.last_part[sens], 0)])
                                | ((rays.last_event[sens] == EVENT_DIFFRACTION) & (rays.last_pdf_per_sr[sens] > 0)))
        i = sens[shared]
        p_nee = settings.nee_samples * (t[i] * t[i]) / (scene.detector_area_mm2[j[shared]] * np.abs(cos_in[i]))
        w_det[shared] = w[i] * power_heuristic_rows(rays.last_pdf_per_sr[i], p_nee)
        M[rows.nee_exchange + rays.last_part[i], r[i]] += w[i] - w_det[shared]
    counted = w_det > 0
    M[rows.detector_direct + j[counted], r[sens[counted]]] += w_det[counted]
    absorber = np.flatnonzero(role == ROLE_ABSORBER)
    M[rows.absorbed + part[absorber], r[absorber]] += w[absorber]
    cont = np.flatnonzero((role >= 0) & (role != ROLE_DETECTOR) & (role != ROLE_ABSORBER))
    return cont, p, nf, part, t, cos_in, sens[counted], w_det[counted]
