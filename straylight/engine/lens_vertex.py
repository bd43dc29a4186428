"""First scatter vertices lit through a lens, area-sampled and joined to the beam by solving the lens
(``EstimatorOptions.lens_vertex``; docs/engine.md, "Scatter points lit through a lens").

Behind a lens the beam lights a scatter point x only through the glass: "source -> lens faces (T ... T)
-> x -> detector". The walk reaches x through the entrance point u whose refracted ray lands there; where
x is a small face the detector sees at a glint (the guide scope at 15 deg: the lens cell's bore, 0.9 mm
tall, lit through a crescent of the beam a fraction of a millimetre wide, ~10 % of the power and most of
the variance) it finds that u rarely and first-vertex sampling (straylight.engine.first_vertex) cannot
join x to the source: the shadow ray stops at the glass. Here x is drawn on the surface triangles
directly (a table learnt from probes, as first-vertex sampling's) and joined to the beam through the
*run*, the sequence of refracting analytic surfaces the beam crosses before it (found by tracing the beam
with every interface transmitting, :func:`find_runs`):

- the entrance point u (coordinates (a, b) on the source disk) is solved for by Gauss-Newton on the
  offset of u's refracted ray from x, perpendicular to that ray (a forward-difference Jacobian J, 3 x 2);
- the irradiance at x is E = Phi S_0 / (pi r^2 |J_a x J_b|) |cos_x|: the source's power per disk area
  Phi / (pi r^2), spread by the run over |J_a x J_b| of area across the ray (the beam's compression),
  S_0 the run's Fresnel throughput for the unpolarized beam (the Stokes vector carried through each
  interface's Mueller matrix, frames turned between them; bulk absorption included);
- the arriving Stokes vector S enters the BRDF as the walk's does (``M[0] . S`` on a polarizing material);
- every segment is cast (source -> X_1 -> ... -> X_L -> x -> z): each must meet exactly its intended point.

The walk's density of the same vertex (area measure, per ray) is p_F = |cos_x| G^2 P_c / (pi r^2 |J_a x J_b|)
(G^2 P_c the entrance table's density of u relative to the uniform disk, 1 without one; the run's branch
probabilities left out: any function of x that both sides compute alike keeps the weights a partition of
unity), computed on the walk's side from the same solve at its own hit point. The walk's path *is* the run
where its ray, traced back through the run's surfaces (refraction reversed), leaves the first along the beam
from a point of the disk that the solve also finds (a point two rays of a run reach keeps the walk's whole
weight for the one the solve does not find). Both sides take the balance heuristic, w = p / (p_F + p_A) (Veach 1997, ch. 9): the walk's NEE
from x and its hits on a detector straight after x keep p_F / (p_F + p_A). Each ray id draws one vertex per
detector here (an own stream per chunk), so the rays stay independent. Contributions go to
the detector and, negated, to x's part's NEE-exchange row (the ledger stays exact)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from geometry.analytic import Conic
from materials.mueller import apply_interface_mueller, rotate_stokes, s_vector
from materials.polarized_brdf import is_polarizing, mueller_brdf
from materials.smooth import Dielectric, refract
from straylight.engine import first_vertex
from straylight.engine.capabilities import Capability
from straylight.engine.first_vertex import PROBE_BUDGET, _local, probe_scores
from straylight.engine.interactions.registry import parts_with
from straylight.engine.lobes import lobe_materials
from straylight.engine.material_groups import by_material
from straylight.engine.ray_batch import EVENT_DETECTOR, EVENT_SCATTER, EVENT_SPECULAR
from straylight.engine.reverse_chain import scatter_ends
from straylight.engine.specular_nee import _eta, _meets
from straylight.engine.surface_geometry import branch_coefficients
from straylight.engine.triangle_sampling import triangle_areas, triangle_points
from straylight.engine.vec3 import power_heuristic_rows
from straylight.engine.walk_shares import keep_walk_share
from straylight.paths import mix_key
from straylight.rng import CHUNK_RAYS, check_seed, chunk_bounds
from straylight.sources import CollimatedDisk, orthonormal_basis

STREAM = 0x4C4E5356  # third entropy word of this strategy's streams ("LNSV")
PROBE_STREAM = 0x4C4E5350  # its probes' ("LNSP")
MAX_RUN = 6  # interfaces in a run
FIND_RAYS = 64  # the beam traced for the runs: FIND_RAYS^2 rays on a grid over the source disk
MIN_RUN_RAYS = 4  # a run is kept when at least this many of those rays follow it to a scatter part
PROBES_PER_TRIANGLE = 8
NEWTON_ITER = 20
SOLVE_TOL_MM = 1e-6  # an accepted solution's offset from x (from a start ~1 mm off: three Jacobians)
STEP_MM = 1e-5  # forward-difference step on the source disk
SAME_POINT_MM = 1e-4  # the walk's entrance point and the solve's agree within this on the disk
SAME_PATH = 1e-9  # 1 - cos of the angle between the walk's direction at the source and the beam's


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


@dataclass(frozen=True)
class Run:
    """Interface parts the beam crosses in order (each by refraction), and the refractive-index ratio
    eta = n_incident / n_transmitted for light arriving on each part's front and back."""

    parts: tuple
    eta_front: tuple
    eta_back: tuple
    focus: tuple | None = None  # where the beam's rays after the run come nearest (the solve's start); None: a window


@dataclass(frozen=True, eq=False)
class LensTable:
    """The runs, and the sampling table over (run, triangle) pairs: ``run``, ``tri``, ``cdf`` (m,) and
    ``p_area`` (n_runs, n_triangles): the area density q / A of each pair (0 where not in the table)."""

    runs: tuple
    run: np.ndarray
    tri: np.ndarray
    cdf: np.ndarray
    p_area: np.ndarray

    @property
    def empty(self) -> bool:
        return len(self.tri) == 0


def unsupported(spec) -> str | None:
    """Why the strategy cannot run with these sources (None when it can)."""
    if len(spec.sources) != 1 or not isinstance(spec.sources[0], CollimatedDisk):
        return "lens_vertex joins scatter points to one collimated_disk source"
    if spec.options.physics.polarization != "u":
        return "it carries the beam's polarization through the lens; this trace fixes s or p"
    if spec.options.estimator.target_parts:
        return "its balance weights use the walk's own densities; target sampling draws from a mixture"
    return None


# ---------------------------------------------------------------------------------------------- runs


def interface_parts(spec) -> np.ndarray:
    """Bool per part: a dielectric interface with an analytic surface (what a run crosses)."""
    ok = parts_with(spec, Capability.DELTA_CHAIN).copy()
    surfaces = spec.part_surfaces or ()
    for p in np.flatnonzero(ok):
        mat = int(spec.part_material[p])
        model = spec.materials[mat] if mat >= 0 else None
        ok[p] = (p < len(surfaces) and isinstance(surfaces[p], Conic)
                 and isinstance(getattr(model, "smooth", None), Dielectric))
    return ok


def _run(spec, parts) -> Run:
    parts = tuple(int(p) for p in parts)
    eta_front, eta_back = tuple(_eta(spec, p, True) for p in parts), tuple(_eta(spec, p, False) for p in parts)
    return Run(parts, eta_front, eta_back, _focus(spec, parts, eta_front, eta_back))


def _disk_frame(src):
    e1, e2 = orthonormal_basis(np.asarray(src.normal, float)[None])
    return e1[0], e2[0]


def _on_disk(src, ab):
    e1, e2 = _disk_frame(src)
    return src.center_mm + ab[:, :1] * e1 + ab[:, 1:2] * e2


def _to_disk(src, p):
    """Points p carried back along the beam onto the disk's plane: (their (a, b) there, the distance t back)."""
    e1, e2 = _disk_frame(src)
    d = np.asarray(src.direction, float)
    t = ((p - src.center_mm) @ src.normal) / float(np.dot(d, src.normal))
    q = p - t[:, None] * d - src.center_mm
    return np.column_stack([q @ e1, q @ e2]), t


def find_runs(spec, comp) -> tuple:
    """The runs of the beam: FIND_RAYS^2 rays on a grid over the source disk traced with every interface
    transmitting (exact surfaces), each run's parts recorded until the ray meets a scatter part from the air;
    the runs at least MIN_RUN_RAYS of them follow, most followed first."""
    src = spec.sources[0]
    iface = interface_parts(spec)
    if not iface.any():
        return ()
    g = (np.arange(FIND_RAYS) + 0.5) / FIND_RAYS * 2.0 - 1.0
    a, b = np.meshgrid(g, g, indexing="ij")
    keep = a * a + b * b < 1.0
    ab = np.column_stack([a[keep], b[keep]]) * src.radius_mm
    o = _on_disk(src, ab)
    d = np.ascontiguousarray(np.broadcast_to(src.direction, o.shape), dtype=float)
    seqs: list[list[int]] = [[] for _ in range(len(o))]
    inside = np.full(len(o), -1)  # the medium the ray is in (a dielectric's material index, -1 air)
    last = np.full(len(o), -1)  # the part each ray crossed last
    live = np.arange(len(o))
    found: dict = {}
    for _ in range(MAX_RUN + 1):
        if len(live) == 0:
            break
        part, again, crossed = transmit_step(spec, comp, iface, o, d, last, live)
        ends = (part >= 0) & ~again & ~iface[np.maximum(part, 0)] & (inside[live] < 0)
        for r in np.flatnonzero(ends):
            if seqs[live[r]]:
                key = tuple(seqs[live[r]])
                found[key] = found.get(key, 0) + 1
        nxt = []
        for p, i, front in crossed:
            inside[i] = np.where(front, int(spec.part_material[p]), -1)
            for k in i:
                seqs[k].append(int(p))
            nxt.append(i)
        nxt.append(live[again])
        live = np.concatenate(nxt)
        live = live[[len(seqs[k]) <= MAX_RUN for k in live]] if len(live) else live
    runs = sorted(((n, key) for key, n in found.items() if n >= MIN_RUN_RAYS), reverse=True)
    return tuple(_run(spec, key) for _, key in runs)


def transmit_step(spec, comp, iface, o, d, last, live) -> tuple:
    """One cast of the rays ``live`` (origins ``o``, unit directions ``d``: updated in place) with every analytic
    interface (``iface``: bool per part, :func:`interface_parts`) transmitting, on the exact surfaces: a ray that
    meets a facet of the part it crossed last (``last``, updated) again is moved past it (a convex face's facets
    lie inside it); one that meets an interface is refracted there (total reflection drops it). Returns, per row of
    ``live``, the part met (-1: nothing) and whether it was such a facet, and per interface part crossed
    ``(part, its rays, arrived on its front)`` in part order."""
    tri, dist = comp.isect.intersect(np.ascontiguousarray(o[live]), np.ascontiguousarray(d[live]))
    tri = np.asarray(tri)
    dist = np.asarray(dist)
    hit = tri >= 0
    part = np.where(hit, spec.triangle_part[np.where(hit, tri, 0)], -1)
    again = hit & (part == last[live])
    o[live[again]] += (dist[again] + 2.0 * spec.eps)[:, None] * d[live[again]]
    go = np.flatnonzero(hit & ~again & iface[np.maximum(part, 0)])
    crossed = []
    surfaces = spec.part_surfaces
    for p in np.unique(part[go]):
        rows = go[part[go] == p]
        i = live[rows]
        X, _, front, d_new, fine = _refract_at(surfaces[p], _eta(spec, p, True), _eta(spec, p, False), o[i], d[i],
                                               dist[rows])
        i, X, front, d_new = i[fine], X[fine], front[fine], d_new[fine]
        if len(i) == 0:
            continue
        d[i] = d_new
        o[i] = X + 2.0 * spec.eps * d_new
        last[i] = p
        crossed.append((int(p), i, front))
    return part, again, crossed


# ---------------------------------------------------------------------------------------------- tracing


def _start_distance(surf, o, d):
    """Distance from o along d to the surface's vertex plane (a start for the exact hit)."""
    ol = surf.to_local(o)
    dl = surf.dirs_to_local(d)
    dz = np.where(np.abs(dl[:, 2]) > 1e-12, dl[:, 2], 1e-12)
    return -ol[:, 2] / dz


def _refract_at(surf, eta_front, eta_back, o, d, t0):
    """Refract rays (o, d) at the exact surface ``surf`` met near distance t0 (eta: n_incident / n_transmitted for
    light arriving on its front or back): (X, facing normal, arrived on front, new d, ok: met, no total
    reflection)."""
    t, nrm, ok = surf.refine_hits(o, d, t0)
    ok = ok & (t > 0) & np.isfinite(t)
    X = o + np.where(ok, t, 0.0)[:, None] * d
    front = _dot(d, nrm) < 0
    nf = np.where(front[:, None], nrm, -nrm)
    eta = np.where(front, eta_front, eta_back)
    cos_i = np.clip(-_dot(d, nf), 0.0, 1.0)
    sin2 = eta * eta * (1.0 - cos_i * cos_i)
    ok &= sin2 < 1.0
    d_new = refract(d, nf, eta, np.sqrt(np.clip(1.0 - sin2, 0.0, 1.0)))
    return X, nf, front, d_new, ok


def _cross(spec, run: Run, i: int, o, d):
    """Refract rays (o, d) at the run's i-th surface (:func:`_refract_at`, started at its vertex plane)."""
    surf = spec.part_surfaces[run.parts[i]]
    return _refract_at(surf, run.eta_front[i], run.eta_back[i], o, d, _start_distance(surf, o, d))


def trace_run(spec, run: Run, ab):
    """The beam's rays from disk coordinates ``ab`` through the run: (points (L, m, 3), exit direction, ok)."""
    src = spec.sources[0]
    o = _on_disk(src, ab)
    d = np.ascontiguousarray(np.broadcast_to(src.direction, o.shape), dtype=float)
    ok = np.einsum("ij,ij->i", ab, ab) < src.radius_mm ** 2
    pts = []
    for i in range(len(run.parts)):
        o, _, _, d, ok_i = _cross(spec, run, i, o, d)
        ok &= ok_i
        pts.append(o)
    return np.stack(pts), d, ok


def _offset(x, X_last, d_out):
    """x's offset from the exit ray (X_last, d_out), perpendicular to it (m, 3)."""
    v = x - X_last
    return v - _dot(v, d_out)[:, None] * d_out


def jacobian(spec, run: Run, ab, x):
    """(offset of the ray from x, J (m, 3, 2): its derivatives in a and b, exit ray (X, d), ok)."""
    X, d, ok = trace_run(spec, run, ab)
    r0 = _offset(x, X[-1], d)
    J = np.empty((len(ab), 3, 2))
    for k in range(2):
        step = np.zeros_like(ab)
        step[:, k] = STEP_MM
        Xk, dk, okk = trace_run(spec, run, ab + step)
        ok &= okk
        J[:, :, k] = (_offset(x, Xk[-1], dk) - r0) / STEP_MM
    return r0, J, X, d, ok


def _area_ratio(J):
    """|J_a x J_b|: the area across the ray at x per area of the source disk."""
    return np.linalg.norm(np.cross(J[:, :, 0], J[:, :, 1]), axis=1)


def _focus(spec, parts, eta_front, eta_back):
    """The nearest point of five of the beam's rays after the surfaces (a run's focus), or None (a window)."""
    src = spec.sources[0]
    fan = np.array([[0.0, 0.0], [0.3, 0.0], [0.0, 0.3], [-0.3, 0.0], [0.0, -0.3]]) * src.radius_mm
    X, dout, ok = trace_run(spec, Run(parts, eta_front, eta_back), fan)
    if ok.sum() < 3:
        return None
    A = np.zeros((3, 3))
    rhs = np.zeros(3)
    for p, u in zip(X[-1][ok], dout[ok]):
        M = np.eye(3) - np.outer(u, u)
        A += M
        rhs += M @ p
    if np.linalg.cond(A) > 1e8:
        return None
    return tuple(np.linalg.solve(A, rhs))


def _start(spec, run: Run, x):
    """Start points on the disk: x's line through the run's focus met with the first surface's vertex plane,
    carried back along the beam; x carried straight back where the run has no focus (a window)."""
    src = spec.sources[0]
    ab = _to_disk(src, x)[0]
    if run.focus is None:
        return ab
    focus = np.asarray(run.focus)
    surf = spec.part_surfaces[run.parts[0]]
    axis = surf.dirs_to_world(np.array([[0.0, 0.0, 1.0]]))[0]
    v = x - focus
    den = v @ axis
    t = ((surf.vertex_mm - focus) @ axis) / np.where(np.abs(den) > 1e-12, den, 1e-12)
    q = focus + t[:, None] * v
    far = ~np.isfinite(t) | (np.abs(den) <= 1e-12)
    return np.where(far[:, None], ab, _to_disk(src, q)[0])


def solve(spec, run: Run, x):
    """Entrance points (a, b) whose rays reach x through the run: (ab, J, exit points, exit d, ok)."""
    ab = _start(spec, run, x)
    m = len(x)
    ok = np.ones(m, dtype=bool)
    done = np.zeros(m, dtype=bool)
    J = np.zeros((m, 3, 2))
    X = np.zeros((len(run.parts), m, 3))
    d = np.zeros((m, 3))
    cap = 0.25 * spec.sources[0].radius_mm  # a step is clipped to a quarter of the disk's radius
    for _ in range(NEWTON_ITER + 1):
        act = np.flatnonzero(ok & ~done)
        if len(act) == 0:
            break
        r0, Ja, Xa, da, okj = jacobian(spec, run, ab[act], x[act])
        J[act], X[:, act], d[act] = Ja, Xa, da
        ok[act] &= okj
        met = okj & (np.linalg.norm(r0, axis=1) <= SOLVE_TOL_MM)
        done[act] = met
        JT = np.transpose(Ja, (0, 2, 1))
        A = JT @ Ja
        g = np.einsum("nij,nj->ni", JT, r0)
        det = A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] * A[:, 1, 0]
        good = np.abs(det) > 1e-30
        ok[act[~good & ~met]] = False
        sd = np.where(good, det, 1.0)
        step = -np.column_stack([(A[:, 1, 1] * g[:, 0] - A[:, 0, 1] * g[:, 1]) / sd,
                                 (A[:, 0, 0] * g[:, 1] - A[:, 1, 0] * g[:, 0]) / sd])
        size = np.linalg.norm(step, axis=1)
        step *= np.minimum(1.0, cap / np.maximum(size, 1e-300))[:, None]
        move = good & ~met
        ab[act[move]] += step[move]
    ok &= done & (_dot(x - X[-1], d) > 0)
    return ab, J, X, d, ok


def recover(spec, run: Run, x, d_arrive):
    """The walk's side: its rays arriving at x along ``d_arrive``, traced back through the run. Returns (ab, is the run): ``is the run`` where the ray, reversed, crosses
    every surface of the run and leaves the first along the beam from a point of the disk."""
    src = spec.sources[0]
    m = len(x)
    o = np.ascontiguousarray(x, dtype=float)
    d = np.ascontiguousarray(d_arrive, dtype=float)
    ok = np.ones(m, dtype=bool)
    L = len(run.parts)
    for i in range(L - 1, -1, -1):
        surf = spec.part_surfaces[run.parts[i]]
        # the surface met backward from here (from x first: the walk's origin sits eps off the surface)
        t, _, fine = surf.refine_hits(o, -d, _start_distance(surf, o, -d))
        ok &= fine & (t > 0)
        o = o + np.where(ok, t, 0.0)[:, None] * (-d)
        nrm = surf.normals(o)
        # reversed light (-d) arrives on the side the forward light left by
        back_front = _dot(-d, nrm) < 0
        nf = np.where(back_front[:, None], nrm, -nrm)
        eta = np.where(back_front, run.eta_front[i], run.eta_back[i])
        cos_i = np.clip(-_dot(-d, nf), 0.0, 1.0)
        sin2 = eta * eta * (1.0 - cos_i * cos_i)
        ok &= sin2 < 1.0
        d = -refract(-d, nf, eta, np.sqrt(np.clip(1.0 - sin2, 0.0, 1.0)))
    ok &= 1.0 - _dot(d, np.broadcast_to(src.direction, d.shape)) <= SAME_PATH
    ab, t = _to_disk(src, o)
    ok &= (t > 0) & (np.einsum("ij,ij->i", ab, ab) < src.radius_mm ** 2)
    return ab, ok


def entrance_factor(spec, ab):
    """The walk's density of entrance points ab relative to the uniform disk: G^2 P_c of the entrance table's
    cell (straylight.engine.entrance_sampling.warp), 1 without a table."""
    table = spec.entrance_table
    if table is None or len(ab) == 0:
        return np.ones(len(ab))
    u = spec.sources[0].uniforms_at(_on_disk(spec.sources[0], ab))
    g = int(table.grid)
    i = np.minimum((u[:, 0] * g).astype(np.int64), g - 1)
    j = np.minimum((u[:, 1] * g).astype(np.int64), g - 1)
    return g * g * table.prob[i * g + j]


def _forward_density(spec, ab, area, cos_x):
    """p_F = |cos_x| G^2 P_c / (pi r^2 |J_a x J_b|): the walk's area density at x per ray (module doc)."""
    return cos_x * entrance_factor(spec, ab) / (math.pi * spec.sources[0].radius_mm ** 2 * area)


def walk_density(spec, run: Run, x, normals):
    """p_F (area density at x per ray, uniform entrance) of the run's ray that :func:`solve` finds for x, and
    that ray's entrance point: (p_F, ab, ok). Both sides take it from the same solve (a function of x)."""
    ab, J, _, d, ok = solve(spec, run, x)
    area = _area_ratio(J)
    ok &= area > 0
    p_f = np.where(ok, _forward_density(spec, ab, np.where(ok, area, 1.0), np.abs(_dot(normals, d))), 0.0)
    return p_f, ab, ok


def stokes_through(spec, run: Run, ab):
    """The Stokes vector (m, 4; S_0 the power of a unit unpolarized ray) leaving the run, in the frame e1
    (the last interface's s vector), with e1 and the exit points and direction."""
    src = spec.sources[0]
    o = _on_disk(src, ab)
    d = np.ascontiguousarray(np.broadcast_to(src.direction, o.shape), dtype=float)
    S = np.zeros((len(ab), 4))
    S[:, 0] = 1.0
    e1 = None
    prev = o
    for i, p in enumerate(run.parts):
        X, nf, front, d_new, _ = _cross(spec, run, i, o, d)
        dist = np.linalg.norm(X - prev, axis=1)
        _, _, ts, tp, _, _, bulk = branch_coefficients(spec, np.full(len(ab), p, dtype=np.int64), front, d, nf, dist)
        e_new = s_vector(d, nf)
        if e1 is not None:
            S = rotate_stokes(S, e1, e_new, d)
        S = apply_interface_mueller(ts, tp, S) * bulk[:, None]
        e1, prev, o, d = e_new, X, X, d_new
    return S, e1, o, d


# ---------------------------------------------------------------------------------------------- contributions


def _brdf(spec, mat, wi_loc, wo_loc, S, s_loc):
    """f for the arriving Stokes vectors S (frame s_loc, local): ``M[0] . S`` on polarizing materials."""
    f = np.empty(len(mat))
    for rows, fv in by_material(spec.materials, mat, lambda model, rows: model.brdf(wi_loc[rows], wo_loc[rows], "u")):
        f[rows] = fv
    for k in np.unique(mat):
        model = spec.materials[k]
        if not is_polarizing(model):
            continue
        g = np.flatnonzero(mat == k)
        M, _ = mueller_brdf(model, wi_loc[g], wo_loc[g], s_loc[g], first_row_only=True)
        f[g] = np.einsum("nj,nj->n", M[:, 0, :], S[g])
    return f


def connect(spec, comp, run: Run, t, x, u_det, j, u_lobe=None):
    """Single-scatter contributions E f cos_x cos_z / d^2 (per area of x and z) of points x on triangles t,
    lit through the run, toward a uniform point of detector j (with ``u_lobe``, 3 uniforms per point: combined
    with a draw from a glossy material's lobe, :func:`_with_lobe_draws`): (value, z, p_F, casts)."""
    src = spec.sources[0]
    eps = spec.eps
    m = len(x)
    value = np.zeros(m)
    p_f = np.zeros(m)
    z, n_det = comp.detectors[j].sample(u_det)
    ab, J, X, d, ok = solve(spec, run, x)
    n_geo = comp.normals[t]
    cos_g = -_dot(d, n_geo)
    ok &= np.abs(cos_g) > 0
    casts = 0
    g = np.flatnonzero(ok)
    if len(g) == 0:
        return value, z, p_f, casts
    area = _area_ratio(J[g])
    ok[g] &= area > 0
    g = g[area > 0]
    area = area[area > 0]
    nf = np.where((cos_g[g] >= 0)[:, None], n_geo[g], -n_geo[g])
    v = z[g] - x[g]
    d2 = _dot(v, v)
    dist = np.sqrt(d2)
    wo = v / np.where(dist > 0, dist, 1.0)[:, None]
    cos_o = _dot(wo, nf)
    cos_z = -_dot(wo, n_det[g])
    if spec.options.output.detector_sides == "both":
        cos_z = np.abs(cos_z)
    good = (cos_o > 0) & (cos_z > 0) & (dist > 2 * eps)
    g, area, nf, wo, d2, cos_o, cos_z = (a[good] for a in (g, area, nf, wo, d2, cos_o, cos_z))
    if len(g) == 0:
        return value, z, p_f, casts
    # every segment, cast: the disk -> X_1 -> ... -> X_L (each meeting its surface), X_L -> x, x -> z
    here = _on_disk(src, ab[g])
    last = np.full(len(g), -1, dtype=np.int64)
    alive = np.ones(len(g), dtype=bool)
    for i, p in enumerate(run.parts):
        sub = np.flatnonzero(alive)
        met, n = _meets(spec, comp, here[sub], X[i][g[sub]], last[sub], p, spec.part_surfaces[p])
        casts += n
        alive[sub[~met]] = False
        here = X[i][g]
        last = np.full(len(g), p, dtype=np.int64)
    sub = np.flatnonzero(alive)
    tpart = spec.triangle_part[t[g[sub]]].astype(np.int64)
    met, n = _meets(spec, comp, here[sub], x[g[sub]], last[sub], tpart, None)
    casts += n
    alive[sub[~met]] = False
    sub = np.flatnonzero(alive)
    origin = x[g[sub]] + eps * nf[sub]
    to_det = z[g[sub]] - origin
    ld = np.linalg.norm(to_det, axis=1)
    blocked = np.asarray(comp.isect.occluded(np.ascontiguousarray(origin), np.ascontiguousarray(to_det / ld[:, None]),
                                             ld - eps), dtype=bool)
    casts += len(sub)
    alive[sub[blocked]] = False
    keep = np.flatnonzero(alive)
    g, area, nf, wo, d2, cos_o, cos_z = (a[keep] for a in (g, area, nf, wo, d2, cos_o, cos_z))
    if len(g) == 0:
        return value, z, p_f, casts
    S, e1, _, d_out = stokes_through(spec, run, ab[g])
    tb, bb = orthonormal_basis(nf)
    wi_loc = _local(-d_out, tb, bb, nf)
    wo_loc = _local(wo, tb, bb, nf)
    s_loc = _local(e1, tb, bb, nf)
    mat = spec.part_material[spec.triangle_part[t[g]]]
    f = _brdf(spec, mat, wi_loc, wo_loc, S / S[:, :1], s_loc)
    cos_x = np.abs(_dot(d_out, nf))
    e_x = src.power_w * S[:, 0] / (math.pi * src.radius_mm ** 2 * area) * cos_x
    value[g] = e_x * f * cos_o * cos_z / d2
    p_f[g] = _forward_density(spec, ab[g], area, cos_x)
    if u_lobe is not None:
        casts += _with_lobe_draws(spec, comp, j, value, g, x[g], nf, tb, bb, mat, wi_loc, wo_loc, S / S[:, :1], s_loc,
                                  e_x, d2, cos_z, u_lobe[g])
    return value, z, p_f, casts


def _with_lobe_draws(spec, comp, j, value, g, x, nf, tb, bb, mat, wi_loc, wo_loc, S, s_loc, e_x, d2, cos_z, u3) -> int:
    """On glossy materials, ``value[g]`` (the uniform detector point's estimate, per area of x and z) becomes
    the power-heuristic combination with a direction drawn from the material's own lobe (``model.sample``),
    kept when its ray reaches detector j first (straylight.engine.first_vertex.lobe_connection: a narrow glint
    is found by the draw, not by a uniform point). Returns the casts."""
    glossy = np.flatnonzero(lobe_materials(spec)[mat])
    if len(glossy) == 0:
        return 0
    area_det = comp.detectors[j].area_mm2
    mg = mat[glossy]
    pdf = np.empty(len(glossy))
    for rows, pv in by_material(spec.materials, mg, lambda model, rows: model.pdf(wi_loc[glossy][rows], wo_loc[glossy][rows], "u")):
        pdf[rows] = pv
    p_nee = d2[glossy] / (area_det * cos_z[glossy])  # the uniform detector point, per sr
    value[g[glossy]] *= power_heuristic_rows(p_nee, pdf)
    wo = np.empty((len(glossy), 3))
    weight = np.empty(len(glossy))
    pdf = np.empty(len(glossy))
    wi_g = wi_loc[glossy]
    for rows, smp in by_material(spec.materials, mg, lambda model, rows: model.sample(wi_g[rows], u3[glossy][rows], "u")):
        wo[rows], weight[rows], pdf[rows] = smp.wo, smp.weight, smp.pdf_per_sr
    ok = np.flatnonzero((wo[:, 2] > 0) & (weight > 0) & (pdf > 0))
    if len(ok) == 0:
        return 0
    k = glossy[ok]
    wo, weight, pdf = wo[ok], weight[ok], pdf[ok]
    # the arriving polarization: the draw's weight carries f for the Stokes vector, not the unpolarized f
    f_pol = _brdf(spec, mat[k], wi_loc[k], wo, S[k], s_loc[k])
    f_u = np.empty(len(k))
    for rows, fv in by_material(spec.materials, mat[k], lambda model, rows: model.brdf(wi_loc[k][rows], wo[rows], "u")):
        f_u[rows] = fv
    weight = weight * np.where(f_u > 0, f_pol / np.where(f_u > 0, f_u, 1.0), 0.0)
    d = wo[:, :1] * tb[k] + wo[:, 1:2] * bb[k] + wo[:, 2:3] * nf[k]
    d = np.ascontiguousarray(d / np.linalg.norm(d, axis=1)[:, None])
    origin = np.ascontiguousarray(x[k] + spec.eps * nf[k])
    tri, dist = comp.isect.intersect(origin, d)
    tri = np.asarray(tri)
    dist = np.asarray(dist)
    on = tri >= 0
    on[on] = spec.triangle_part[tri[on]] == comp.det_parts[j]
    h = np.flatnonzero(on)
    if len(h) == 0:
        return len(k)
    cos_in = _dot(d[h], comp.normals[tri[h]])
    front = np.ones(len(h), dtype=bool) if spec.options.output.detector_sides == "both" else cos_in < 0
    ac = np.abs(cos_in)
    h, ac = h[front & (ac > 0)], ac[front & (ac > 0)]
    p_nee = dist[h] ** 2 / (area_det * ac)
    # per area of x and z, as the uniform point's (run_pass multiplies by the detector's area)
    value[g[k[h]]] += e_x[k[h]] * weight[h] * power_heuristic_rows(pdf[h], p_nee) / area_det
    return len(k)


# ---------------------------------------------------------------------------------------------- the table


def _candidates(spec):
    """Surface triangles that may be x: parts area-sampled by first-vertex sampling whose material is a
    scatter end (straylight.engine.reverse_chain.scatter_ends), of positive area."""
    tri_mm = spec.triangles_mm
    ends = scatter_ends(spec)
    part_ok = parts_with(spec, Capability.FIRST_VERTEX) & ends[spec.part_material]
    surf = np.flatnonzero(part_ok[spec.triangle_part])
    area = triangle_areas(tri_mm)
    return surf[area[surf] > 0], area


def _probe(spec, comp, run, tris, m, rng):
    """sqrt(mean g^2) over m probes per triangle of ``tris``, lit through the run (first_vertex.probe_scores)."""
    return probe_scores(spec, comp, tris, m, rng, lambda t, x, u, j: connect(spec, comp, run, t, x, u, j)[0])


def probes_per_triangle(n_triangles: int) -> int:
    """Probes per triangle of the parts lit through a run: PROBES_PER_TRIANGLE, fewer when that would pass
    first-vertex sampling's PROBE_BUDGET (at least one: a 0.5M-triangle housing behind a lens gets one per triangle,
    as first_vertex's table does, instead of 4M probes, seconds per angle)."""
    return first_vertex.probes_per_triangle(n_triangles, PROBE_BUDGET, PROBES_PER_TRIANGLE)


def build_table(spec, comp) -> LensTable:
    """The runs (:func:`find_runs`) and, per run, q over its triangles: one probe per candidate triangle
    finds the parts lit through the run and seen by a detector, then :func:`probes_per_triangle` probes per
    triangle of those parts give q_t proportional to A_t sqrt(mean g^2) (first_vertex's table)."""
    n_tri = len(spec.triangles_mm)
    runs = find_runs(spec, comp)
    empty = LensTable(runs, np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros((len(runs), n_tri)))
    if not runs:
        return empty
    surf, area = _candidates(spec)
    if len(surf) == 0:
        return empty
    rng = np.random.default_rng([check_seed(spec.seed), PROBE_STREAM])
    pairs_run, pairs_tri, scores = [], [], []
    for k, run in enumerate(runs):
        first = _probe(spec, comp, run, surf, 1, rng)
        parts = np.unique(spec.triangle_part[surf[first > 0]])
        tris = surf[np.isin(spec.triangle_part[surf], parts)]
        if len(tris) == 0:
            continue
        score = area[tris] * _probe(spec, comp, run, tris, probes_per_triangle(len(tris)), rng)
        keep = score > 0
        pairs_run.append(np.full(int(keep.sum()), k, dtype=np.int64))
        pairs_tri.append(tris[keep].astype(np.int64))
        scores.append(score[keep])
    if not scores or sum(len(s) for s in scores) == 0:
        return empty
    run_of, tri, score = np.concatenate(pairs_run), np.concatenate(pairs_tri), np.concatenate(scores)
    q = score / score.sum()
    p_area = np.zeros((len(runs), n_tri))
    p_area[run_of, tri] = q / area[tri]
    return LensTable(runs, run_of, tri, np.cumsum(q), p_area)


def glint_entrances(spec, table: LensTable, n_points: int, seed_words) -> np.ndarray:
    """Entrance points of the beam that light the table's scatter points: ``n_points`` points x drawn from the
    table (q over (run, triangle), uniform on the triangle), each solved for through its run; returns their
    source uniforms (m, 2) (:meth:`CollimatedDisk.uniforms_at`; the points the solve does not find are left out).
    The entrance table's lens component (straylight.engine.entrance_sampling.with_component): on the guide
    scope at 15 deg these are the crescent of the beam whose rays graze the lens cell's bore and whose back-face
    reflection lights its lip, both seen at a glint."""
    if table.empty or n_points <= 0:
        return np.zeros((0, 2))
    rng = np.random.default_rng(list(seed_words))
    pick = np.minimum(np.searchsorted(table.cdf, rng.random(n_points), side="right"), len(table.tri) - 1)
    tri_mm = spec.triangles_mm[table.tri[pick]]
    a, b = rng.random(n_points), rng.random(n_points)
    fold = a + b > 1.0
    a[fold], b[fold] = 1.0 - a[fold], 1.0 - b[fold]
    x = tri_mm[:, 0] + a[:, None] * (tri_mm[:, 1] - tri_mm[:, 0]) + b[:, None] * (tri_mm[:, 2] - tri_mm[:, 0])
    src = spec.sources[0]
    found = []
    for k, run in enumerate(table.runs):
        sel = np.flatnonzero(table.run[pick] == k)
        if len(sel):
            ab, _, _, _, ok = solve(spec, run, x[sel])
            found.append(src.uniforms_at(_on_disk(src, ab[ok])))
    return np.concatenate(found) if found else np.zeros((0, 2))


# ---------------------------------------------------------------------------------------------- the pass


def run_pass(spec, comp, table: LensTable, first_chunk, stop_chunk, tallies, rows, records, record_paths,
             path_depth) -> int:
    """This strategy's MIS-weighted estimates for chunks ``first_chunk .. stop_chunk-1`` (one sample per ray
    id and detector) added to ``tallies``. Returns the casts."""
    if table.empty:
        return 0
    C = CHUNK_RAYS
    n_total = spec.n_rays
    sizes = [chunk_bounds(k, n_total)[1] - k * C for k in range(first_chunk, stop_chunk)]
    D = len(comp.det_parts)
    u_all = np.concatenate([np.random.default_rng([check_seed(spec.seed), spec.chunk_offset + first_chunk + c, STREAM])
                            .random((sizes[c], 9 * D)) for c in range(len(sizes))])
    casts = 0
    for j in range(D):
        u = u_all[:, 9 * j:9 * j + 9]
        k = np.minimum(np.searchsorted(table.cdf, u[:, 0] * table.cdf[-1], side="right"), len(table.tri) - 1)
        t, which = table.tri[k], table.run[k]
        x = triangle_points(spec.triangles_mm, t, u[:, 1], u[:, 2])
        for r_i, run in enumerate(table.runs):
            sel = np.flatnonzero(which == r_i)
            if len(sel) == 0:
                continue
            value, z, p_f, n = connect(spec, comp, run, t[sel], x[sel], u[sel, 3:6], j, u[sel, 6:9])
            casts += n
            good = np.flatnonzero(value > 0)
            if len(good) == 0:
                continue
            r = sel[good]
            p_a = table.p_area[r_i, t[r]]
            c = value[good] * comp.detectors[j].area_mm2 / (p_a + p_f[good]) / n_total
            _add_terms(spec, comp, j, run, tallies, rows, records, record_paths, path_depth, r, t[r], z[good], c)
    return casts


def _add_terms(spec, comp, j, run, tallies, rows, records, record_paths, path_depth, r, tg, z, c):
    """Contributions ``c`` of rays ``r`` (vertices on triangles ``tg``) to detector j and their path records
    (the run's refractions, the scatter, the detector); the same leaves the part's NEE-exchange row."""
    pt = spec.triangle_part[tg].astype(np.int64)
    tallies.add(rows.detector_nee + j, r, c)
    tallies.subtract(rows.nee_exchange + pt, r, c)
    keys = events = None
    if record_paths:
        codes = [p * 4 + EVENT_SPECULAR for p in run.parts]
        key = np.zeros(len(r), dtype=np.uint64)
        for code in codes:
            key = mix_key(key, code)
        key = mix_key(key, pt * 4 + EVENT_SCATTER)
        keys = mix_key(key, comp.det_parts[j] * 4 + EVENT_DETECTOR)
        events = np.full((len(r), path_depth), -1, dtype=np.int16)
        for i, code in enumerate(codes[:path_depth]):
            events[:, i] = code
        if len(codes) < path_depth:
            events[:, len(codes)] = pt * 4 + EVENT_SCATTER
    records.add(j, r, z, c, keys, events, np.full(len(r), len(run.parts) + 1, dtype=np.int64))


# ---------------------------------------------------------------------------------------------- the walk's side


class LensVertexWeights:
    """The walk's side: the balance weight p_F / (p_F + p_A) of its first scatter vertices reached through a
    run, applied to their NEE (:meth:`vertex_weights`) and kept per ray for its hit on a detector straight
    after that vertex (:meth:`share_walk_hits`)."""

    def __init__(self, spec, table: LensTable, n_rays_in_batch):
        self.spec = spec
        self.table = table
        self.w_ray = np.ones(n_rays_in_batch)
        self.at_depth = np.full(n_rays_in_batch, -1, dtype=np.int64)
        self.lengths = {len(run.parts) for run in table.runs}

    def vertex_weights(self, event, verts, w_vertex):
        rays = event.rays
        depth = rays.depth[verts]
        cand = np.flatnonzero((rays.last_event[verts] == EVENT_SPECULAR) & np.isin(depth, list(self.lengths)))
        if len(cand) == 0:
            return w_vertex
        w = None
        for r_i, run in enumerate(self.table.runs):
            at = cand[(depth[cand] == len(run.parts)) & (rays.last_part[verts[cand]] == run.parts[-1])]
            if len(at) == 0:
                continue
            i = verts[at]
            p_a = self.table.p_area[r_i, event.tri[i]]
            at, i, p_a = at[p_a > 0], i[p_a > 0], p_a[p_a > 0]
            if len(at) == 0:
                continue
            x = event.hits.point_mm[i]
            ab, same = recover(self.spec, run, x, rays.direction[i])
            at, i, p_a, x, ab = at[same], i[same], p_a[same], x[same], ab[same]
            if len(at) == 0:
                continue
            p_f, ab_s, ok = walk_density(self.spec, run, x, event.scene.normals[event.tri[i]])
            # the strategy draws this path only where its solve finds the walk's own entrance point (a point
            # reached by two rays of the run keeps the walk's whole weight for the one the solve does not find)
            ok &= np.linalg.norm(ab_s - ab, axis=1) <= SAME_POINT_MM
            at, i, p_a, p_f = at[ok], i[ok], p_a[ok], p_f[ok]
            if len(at) == 0:
                continue
            share = p_f / (p_f + p_a)
            if w is None:
                w = np.ones(len(verts)) if w_vertex is None else np.array(w_vertex, dtype=float)
            w[at] *= share
            self.w_ray[rays.ray[i]] = share
            self.at_depth[rays.ray[i]] = depth[at] + 1
        return w_vertex if w is None else w

    def share_walk_hits(self, event, rec, rec_w):
        """Walk hits on a detector straight after such a vertex keep their share (the rest to the NEE
        exchange: the ledger stays exact)."""
        rays = event.rays
        ray = rays.ray[rec]
        sel = np.flatnonzero((rays.last_event[rec] == EVENT_SCATTER) & (rays.depth[rec] == self.at_depth[ray]))
        if len(sel) == 0:
            return rec, rec_w
        return keep_walk_share(event, rec, rec_w, sel, self.w_ray[ray[sel]])
