"""The surface geometry and Fresnel physics of interface hits, shared by the surface response that
branches at them (straylight.engine.interactions.optical_surface), the strategy that splits through runs
of them (straylight.engine.delta_chain) and thermal's reverse walk (straylight.thermal.interaction): the
mesh hit refined onto the part's analytic surface, the material of the side that was hit, the Fresnel
amplitudes (``Material.smooth_coefficients``) with the bulk attenuation of the medium crossed, the
branch drawn by expected power (:func:`fresnel_branches`) and the reflected / refracted rays with
their Mueller matrices (:func:`delta_branches`): one copy of the surface physics."""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from materials.mueller import apply_interface_mueller
from materials.smooth import Dielectric, reflect, refract
from materials.sampling import lazy_njit
from straylight.engine.material_groups import distinct
from straylight.engine.vec3 import take_rows
from straylight.intersect._plane import plane_distance

SELF_HIT_MM = 1e-6  # a refined hit this close to (or behind) the ray's origin on its own last part is spurious


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


def refine_on_surfaces(spec, part, origin, d, distance_mm, last_part, front, facing):
    """Mesh hits (``origin + distance_mm d`` on ``part``) refined onto the parts' analytic surfaces:
    (front, facing normal, exact point, refined, passing). ``front`` and ``facing`` (the facet's)
    are updated in place where refined; a hit that refines outside the clear aperture or back onto
    the ray's own origin on its last part passes through (``passing``). Each part's rows are written
    in one compiled pass (:func:`_refined_rows_loop`, :func:`refine_on_surfaces_numpy`'s operations in
    its order: the same bits)."""
    m = len(part)
    exact = np.zeros((m, 3))
    refined = np.zeros(m, bool)
    passing = np.zeros(m, bool)
    surfaces = spec.part_surfaces or ()
    o64 = d64 = last64 = None
    for p in distinct(part):
        surf = surfaces[p] if p < len(surfaces) else None
        if surf is None:
            continue
        if o64 is None:
            o64, d64 = np.ascontiguousarray(origin, np.float64), np.ascontiguousarray(d, np.float64)
            last64 = np.ascontiguousarray(last_part, np.int64)
        g = np.flatnonzero(part == p)
        if len(g) == m:  # one part: its rows are all the rows, in order
            t, n_front, ok = surf.refine_hits(o64, d64, distance_mm)
        else:
            t, n_front, ok = surf.refine_hits(take_rows(o64, g), take_rows(d64, g), distance_mm[g])
        lazy_njit(_refined_rows_loop, "numpy")(g, np.ascontiguousarray(t, np.float64),
                                               np.ascontiguousarray(n_front, np.float64),
                                               np.ascontiguousarray(ok, np.bool_), int(p), last64, o64, d64,
                                               SELF_HIT_MM, front, facing, exact, refined, passing)
    return front, facing, exact, refined, passing


def _refined_rows_loop(g, t, n_front, ok, p, last_part, origin, d, self_hit, front, facing, exact, refined,
                       passing):
    """One part's rows ``g`` of :func:`refine_on_surfaces_numpy` (refined distances ``t``, front normals
    ``n_front``, ``ok``) written row by row, in its order (einsum's dot order ``(a0 b0 + a2 b2) + a1 b1``)."""
    for r in range(len(g)):
        i = g[r]
        if not ok[r] or (last_part[i] == p and t[r] < self_hit):
            passing[i] = True
            continue
        d0, d1, d2 = d[i, 0], d[i, 1], d[i, 2]
        exact[i, 0] = origin[i, 0] + t[r] * d0
        exact[i, 1] = origin[i, 1] + t[r] * d1
        exact[i, 2] = origin[i, 2] + t[r] * d2
        n0, n1, n2 = n_front[r, 0], n_front[r, 1], n_front[r, 2]
        fr = ((d0 * n0 + d2 * n2) + d1 * n1) < 0
        front[i] = fr
        if fr:
            facing[i, 0], facing[i, 1], facing[i, 2] = n0, n1, n2
        else:
            facing[i, 0], facing[i, 1], facing[i, 2] = -n0, -n1, -n2
        refined[i] = True


def refine_on_surfaces_numpy(spec, part, origin, d, distance_mm, last_part, front, facing):
    """:func:`refine_on_surfaces` in vectorised numpy (the reference it is tested against)."""
    m = len(part)
    exact = np.zeros((m, 3))
    refined = np.zeros(m, bool)
    passing = np.zeros(m, bool)
    surfaces = spec.part_surfaces or ()
    for p in distinct(part):
        surf = surfaces[p] if p < len(surfaces) else None
        if surf is None:
            continue
        g = np.flatnonzero(part == p)
        t, n_front, ok = surf.refine_hits(take_rows(origin, g), take_rows(d, g), distance_mm[g])
        bad = ~ok | ((last_part[g] == p) & (t < SELF_HIT_MM))
        passing[g[bad]] = True
        keep = ~bad
        good = g[keep]
        nf = n_front[keep]
        d_good = take_rows(d, good)
        exact[good] = take_rows(origin, good) + t[keep, None] * d_good
        fr = _dot(d_good, nf) < 0
        front[good] = fr
        facing[good] = np.where(fr[:, None], nf, -nf)
        refined[good] = True
    return front, facing, exact, refined, passing


class BranchHits(NamedTuple):
    """Where cast branch rays (split trees, eye chains) met the scene: ``hit`` the indices of the
    rays that met a triangle, and for those the triangle, the distance in float64 from the
    triangle's plane (as the walk's hit stage takes it), the part and d . n of the facet."""

    hit: np.ndarray
    tri: np.ndarray
    distance_mm: np.ndarray
    part: np.ndarray
    cos_in: np.ndarray


def cast_branches(spec, scene, origin, d) -> BranchHits:
    """Cast rays ``origin``, ``d`` (contiguous (n, 3)) on ``scene`` (a CompiledScene). The distance is
    ``(n . v0 - n . o) / (d . n)`` of the facet's plane; the intersector's own (plane_distance) only
    where the ray runs edge-on (|d . n| < 1e-12), so an intersector that can return the triangles
    alone (``intersect_triangles``, looked up on its class) skips computing it for every hit."""
    isect = scene.isect
    if not hasattr(type(isect), "intersect_triangles"):
        return _cast_with_distances(spec, scene, origin, d)
    tri = np.asarray(isect.intersect_triangles(origin, d))
    hit = np.flatnonzero(tri >= 0)
    tri = np.ascontiguousarray(tri[hit], dtype=np.int64)
    m = len(hit)
    part, cos_in, dist = np.empty(m, np.int64), np.empty(m), np.empty(m)
    if m:  # _branch_hits in one compiled pass (its operations in its order: the same bits)
        lazy_njit(_branch_hits_loop, "numpy")(hit, tri, np.ascontiguousarray(origin, np.float64),
                                              np.ascontiguousarray(d, np.float64), spec.triangle_part,
                                              scene.normals, scene.arrays.plane_d, part, cos_in, dist)
    edge = np.flatnonzero(~(np.abs(cos_in) >= 1e-12))
    if len(edge):
        v0, normal, centroid = isect.planes
        dist[edge] = plane_distance(v0, normal, centroid, tri[edge], origin[hit[edge]], d[hit[edge]])
    return BranchHits(hit, tri, dist, part, cos_in)


def _branch_hits_loop(hit, tri, origin, d, triangle_part, normals, plane_d, part, cos_in, dist):
    """:func:`_branch_hits` row by row (einsum's dot order ``(a0 b0 + a2 b2) + a1 b1``); the edge-on
    rows' distances are the caller's."""
    for r in range(len(hit)):
        i = hit[r]
        k = tri[r]
        n0, n1, n2 = normals[k, 0], normals[k, 1], normals[k, 2]
        c = (d[i, 0] * n0 + d[i, 2] * n2) + d[i, 1] * n1
        part[r] = triangle_part[k]
        cos_in[r] = c
        den = c if abs(c) >= 1e-12 else 1.0
        dist[r] = (plane_d[k] - ((n0 * origin[i, 0] + n2 * origin[i, 2]) + n1 * origin[i, 1])) / den


def _cast_with_distances(spec, scene, origin, d) -> BranchHits:
    """:func:`cast_branches` on an intersector that returns the triangles with their distances only."""
    tri, dist = scene.isect.intersect(origin, d)
    tri, dist = np.asarray(tri), np.asarray(dist, dtype=np.float64)
    hit = np.flatnonzero(tri >= 0)
    dist = dist[hit]
    return _branch_hits(spec, scene, hit, tri[hit], origin[hit], d[hit], lambda edge: dist[edge])


def _branch_hits(spec, scene, hit, tri, o, dh, edge_distance) -> BranchHits:
    """:class:`BranchHits` of the rays ``hit`` (meeting triangles ``tri`` from ``o`` along ``dh``): the
    plane distance in float64, ``edge_distance(rows)`` where a ray runs edge-on."""
    part = spec.triangle_part[tri].astype(np.int64)
    cos_in = _dot(dh, scene.normals[tri])
    flat = np.abs(cos_in) >= 1e-12
    dist = (scene.arrays.plane_d[tri] - _dot(scene.normals[tri], o)) / np.where(flat, cos_in, 1.0)
    edge = np.flatnonzero(~flat)
    if len(edge):
        dist[edge] = edge_distance(edge)
    return BranchHits(hit, tri, dist, part, cos_in)


def at_interfaces(spec, scene, part, tri, origin, d, distance_mm, last_part, cos_in):
    """Branch rays' hits on interface parts refined onto their exact surfaces: (front, facing normal,
    the point, passing) as :func:`refine_on_surfaces` (the facet's point where not refined). The facet's
    side and the points in compiled passes (:func:`_facet_sides_loop`, :func:`_hit_points_loop`),
    :func:`at_interfaces_numpy`'s operations in its order (the same bits)."""
    m = len(part)
    tri = np.ascontiguousarray(tri, np.int64)
    cos_in = np.ascontiguousarray(cos_in, np.float64)
    front0, facing0 = np.empty(m, np.bool_), np.empty((m, 3))
    if m:
        lazy_njit(_facet_sides_loop, "numpy")(cos_in, tri, scene.normals, front0, facing0)
    origin, d = np.ascontiguousarray(origin, np.float64), np.ascontiguousarray(d, np.float64)
    front, facing, exact, refined, passing = refine_on_surfaces(spec, part, origin, d, distance_mm, last_part,
                                                                front0, facing0)
    at = np.empty((m, 3))
    if m:
        lazy_njit(_hit_points_loop, "numpy")(origin, d, np.ascontiguousarray(distance_mm, np.float64), refined,
                                             exact, at)
    return front, facing, at, passing


def _facet_sides_loop(cos_in, tri, normals, front, facing):
    """Per row: the facet met from its front (``cos_in < 0``) and its normal on the incident side."""
    for r in range(len(tri)):
        k = tri[r]
        fr = cos_in[r] < 0
        front[r] = fr
        if fr:
            facing[r, 0], facing[r, 1], facing[r, 2] = normals[k, 0], normals[k, 1], normals[k, 2]
        else:
            facing[r, 0], facing[r, 1], facing[r, 2] = -normals[k, 0], -normals[k, 1], -normals[k, 2]


def _hit_points_loop(origin, d, distance_mm, refined, exact, at):
    """Per row: the refined point, else ``origin + distance_mm d``."""
    for r in range(len(at)):
        if refined[r]:
            at[r, 0], at[r, 1], at[r, 2] = exact[r, 0], exact[r, 1], exact[r, 2]
        else:
            t = distance_mm[r]
            at[r, 0] = origin[r, 0] + t * d[r, 0]
            at[r, 1] = origin[r, 1] + t * d[r, 1]
            at[r, 2] = origin[r, 2] + t * d[r, 2]


def at_interfaces_numpy(spec, scene, part, tri, origin, d, distance_mm, last_part, cos_in):
    """:func:`at_interfaces` in vectorised numpy (the reference it is tested against)."""
    front0 = cos_in < 0
    n_tri = take_rows(scene.normals, tri)
    facing0 = np.where(front0[:, None], n_tri, -n_tri)
    front, facing, exact, refined, passing = refine_on_surfaces_numpy(spec, part, origin, d, distance_mm, last_part,
                                                                      front0, facing0)
    at = np.where(refined[:, None], exact, origin + distance_mm[:, None] * d)
    return front, facing, at, passing


def branch_coefficients(spec, part, front, d, facing, distance_mm):
    """Fresnel amplitudes of branch rays ``d`` meeting interface parts ``part`` on the side ``front``
    (normal ``facing`` on the incident side, segment ``distance_mm``): ``(r_s, r_p, t_s, t_p, cos_t,
    eta, bulk)`` of :func:`smooth_coefficients_into`, per row."""
    mat = side_material(spec, part, front)
    back = ~front
    cos_i = np.clip(-_dot(d, facing), 0.0, 1.0)
    m = len(part)
    rs, rp, ts, tp = (np.zeros(m, complex) for _ in range(4))
    cos_t, eta, bulk = np.zeros(m), np.ones(m), np.ones(m)
    for k in distinct(mat):
        g = np.flatnonzero(mat == k)
        smooth_coefficients_into(spec.materials[k], g, back, cos_i, distance_mm, (rs, rp, ts, tp, cos_t, eta, bulk))
    return rs, rp, ts, tp, cos_t, eta, bulk


def side_material(spec, part, front):
    """Material index of the side of ``part`` that was hit; a dielectric's back is its medium."""
    m_front = spec.part_material[part]
    back_idx = spec.part_back_material[part] if spec.part_back_material is not None else np.full(len(part), -1)
    return np.where(front | (back_idx < 0), m_front, back_idx)


def smooth_coefficients_into(model, g, back, cos_i, distance_mm, out):
    """Fresnel amplitudes of the rows ``g`` (all of material ``model``) into
    ``out = (r_s, r_p, t_s, t_p, cos_t, eta, bulk)`` (``Material.smooth_coefficients``); ``bulk``
    = exp(-alpha d) for a ray arriving on the back of an absorbing ``dielectric`` (d = ``distance_mm``)."""
    smooth = getattr(model, "smooth", None)
    if smooth is None:
        return
    rs, rp, ts, tp, cos_t, eta, bulk = out
    for side in (False, True):
        gg = g[back[g] == side]
        if len(gg) == 0:
            continue
        c = model.smooth_coefficients(cos_i[gg], back=side)
        rs[gg], rp[gg], ts[gg], tp[gg] = c.r_s, c.r_p, c.t_s, c.t_p
        cos_t[gg], eta[gg] = c.cos_t, c.eta
        if side and isinstance(smooth, Dielectric) and smooth.attenuation_per_mm > 0:
            bulk[gg] = np.exp(-smooth.attenuation_per_mm * distance_mm[gg])


def mix(value_s, value_p, S):
    """The value for light of Stokes S (S0 = 1, s/p basis), no analyser: a v_s + b v_p
    (the first row of a Mueller matrix with M02 = M03 = 0)."""
    return 0.5 * (value_s + value_p) + 0.5 * S[:, 1] * (value_s - value_p)


class Branches(NamedTuple):
    """Per interface hit: the expected powers of its three outcomes and the one drawn (CONTRACTS §5.1)."""

    rho_s: np.ndarray  # lobe reflectance (directional-hemispherical) for s light
    rho_p: np.ndarray  # and for p light
    fresnel: tuple  # (r_s, r_p, t_s, t_p, cos_t, eta, bulk): smooth_coefficients_into
    E_l: np.ndarray  # expected power into the scatter lobes, for the hit's polarization
    E_r: np.ndarray  # specular reflection (after the lobes took theirs)
    E_t: np.ndarray  # transmission (refraction)
    P_l: np.ndarray  # branch probabilities E_x / (E_l + E_r + E_t)
    P_r: np.ndarray
    lobe: np.ndarray  # (m,) bool: the branch drawn
    refl: np.ndarray
    trans: np.ndarray
    dead: np.ndarray  # a live hit with nothing to go on with (E_l + E_r + E_t = 0)


def fresnel_branches(materials, mat, live, back, cos_i, distance_mm, S, u) -> Branches:
    """Branch by probability at interface hits (docs/engine.md, "Branch by probability"): with ``mat``
    the material index (into ``materials``) of the side hit, ``back`` whether it is the back side,
    ``cos_i`` the incidence cosine, ``S`` the arriving Stokes vectors (s/p basis; unpolarized
    ``(1, 0, 0, 0)``) and ``u`` one uniform per hit, the expected powers E_l = a rho_s + b rho_p (the
    lobes), E_r = a |r_s|^2 + b |r_p|^2, E_t likewise (a, b = (1 +- S1) / 2; R and T after the lobes
    took their energy, ``Material.smooth_coefficients``) and the outcome x drawn with probability
    E_x / (E_l + E_r + E_t) (rows where ``live`` is False: none)."""
    m = len(mat)
    rs = np.zeros(m, complex)
    rp = np.zeros(m, complex)
    ts = np.zeros(m, complex)
    tp = np.zeros(m, complex)
    cos_t = np.zeros(m)
    eta = np.ones(m)
    bulk = np.ones(m)
    rho_s = np.zeros(m)
    rho_p = np.zeros(m)
    theta = np.arccos(cos_i)
    for k in distinct(mat[live]):
        g = np.flatnonzero(live & (mat == k))
        model = materials[k]
        if getattr(model, "composite", None) is not None:
            rho_s[g] = model.lobe_reflectance(theta[g], "s")
            rho_p[g] = model.lobe_reflectance(theta[g], "p")
        smooth_coefficients_into(model, g, back, cos_i, distance_mm, (rs, rp, ts, tp, cos_t, eta, bulk))
    E_l = np.where(live, mix(rho_s, rho_p, S), 0.0)
    E_r = np.where(live, mix(np.abs(rs) ** 2, np.abs(rp) ** 2, S), 0.0)
    E_t = np.where(live, mix(np.abs(ts) ** 2, np.abs(tp) ** 2, S), 0.0)
    total = E_l + E_r + E_t
    safe = np.where(total > 0, total, 1.0)
    P_l, P_r = E_l / safe, E_r / safe
    lobe = live & (total > 0) & (u < P_l)
    refl = live & (total > 0) & ~lobe & (u < P_l + P_r)
    trans = live & (total > 0) & ~lobe & ~refl
    dead = live & ~(total > 0)
    return Branches(rho_s, rho_p, (rs, rp, ts, tp, cos_t, eta, bulk), E_l, E_r, E_t, P_l, P_r, lobe, refl, trans, dead)


def lobe_uniforms(u_sample, u, P_l):
    """The lobe branch's sampling uniforms: ``u_sample`` (n, 3) with its first column replaced by the
    branch uniform ``u`` re-used within the lobe's interval [0, P_l) (stratified, no extra draw)."""
    out = u_sample.copy()
    out[:, 0] = np.clip(u / P_l, 0.0, np.nextafter(1.0, 0.0))
    return out


def delta_branches(br: Branches, d, facing, S, direction, throughput, S_new, side_out) -> None:
    """The specular reflection and refraction rows of ``br``: new direction (reflected about, or
    refracted through, the ``facing`` normal), throughput (S0 of the Mueller matrix of the branch,
    ``materials.mueller.interface_mueller`` in the s/p basis, applied to ``S``, over the branch
    probability: the walk's weight times E_x / P_x), the outgoing Stokes vector (normalised, in the
    frame s) and side (-1: crossed), written into the arrays given."""
    rs, rp, ts, tp, cos_t, eta, _bulk = br.fresnel
    for branch, a_s, a_p, P in ((br.refl, rs, rp, br.P_r), (br.trans, ts, tp, 1.0 - br.P_l - br.P_r)):
        b = np.flatnonzero(branch)
        if len(b) == 0:
            continue
        So = apply_interface_mueller(a_s[b], a_p[b], S[b])
        P_b = P[b] if np.ndim(P) else P
        throughput[b] = So[:, 0] / P_b
        S_new[b] = So / np.where(So[:, 0] > 0, So[:, 0], 1.0)[:, None]
        if branch is br.refl:
            direction[b] = reflect(d[b], facing[b])
        else:
            direction[b] = refract(d[b], facing[b], eta[b], cos_t[b])
            side_out[b] = -1
