"""Specular next-event estimation: from a scatter vertex to a detector through one to four interfaces.

Behind or around a lens a scatter point P often reaches the small sensor only through the glass: by
one reflection off a lens face (a vane behind the lens, seen in the flat back face's mirror), by
two refractions (the lens cell's lip, seen through the lens) or by a reflection inside the glass between
two refractions (the vane seen in the lens's thick mirror). Next-event estimation cannot aim
through a refracting or reflecting surface, and the split trees (straylight.engine.delta_chain) hit
the sensor only when the walk's scatter direction happens to go where the run lands on it: on the
guide scope at 5-15 deg those paths held 86-88 % of the variance (benchmarks/variance_paths.py).

At every walk vertex P on a plain scatterer (a non-delta material; straylight.engine.reverse_chain
.scatter_ends), for each candidate sequence S of 1 to ``specular_nee`` (1-4) interfaces (:func:`candidate_sequences`:
every sequence of reflections and transmissions over the parts whose kind declares
``Capability.DELTA_CHAIN`` and that have an analytic conic, asphere or plane surface, no part twice
in a row; with ``specular_nee_sequences = "mirrors"`` only the single reflections and the thick
mirrors "a (T) -> b (R) -> a (T)", :func:`thick_mirror`) and each detector j: a point z uniform on the detector (density 1 / A_j), the interface
points X_i solved for by Newton's method from a deterministic start
(straylight.engine.specular_manifold), every segment checked by a cast (it must meet exactly the
intended surface point, a clear aperture's pass-through refuses the path), and

    w (M_P S_in)_0 cos_P T_S |d omega_P / d A_z| A_j m

added to detector j (its ``detector_nee`` row, taken from the NEE-exchange row of P's part: the
ledger stays exact). M_P S_in is the walk's own polarized scatter at P
(straylight.engine.interactions.scatter_polarization), T_S the Mueller chain's first element on the
scattered Stokes vector times the bulk transmission (as the split trees carry it), |d omega/dA| the
generalized geometry term (Hanika et al. 2015).

Exactly once: the same paths are counted by the split trees rooted at the walk's first interface
hit after P (the walk's own hits after such runs are already the trees', straylight.engine
.delta_chain). The two are combined by the balance heuristic over the direction omega at P:
m = p_nee / (p_nee + p_walk), p_nee = 1 / (A_j |d omega/dA_z|) (solid-angle density of this
estimator's z), p_walk the walk's pdf of omega at P. A tree branch that reaches detector j after
1 to ``specular_nee`` interfaces keeps p_walk / (p_walk + p_nee) (:meth:`SpecularNee.branch_share`), where p_nee is
found by re-running the same deterministic solve for that (P, z, S) and is 0 unless it lands on
the branch's own omega: where Newton misses a solution the tree keeps the whole path, so the sum
stays unbiased whatever the solver finds. Vertices whose runs the reverse chains own (an anchored P,
straylight.engine.reverse_chain.ReverseChains.owns) are left to them.

Requires the split trees (``delta_chain >= specular_nee``), one polarization mode ``u``, no target parts
(its weights use the materials' own pdf). Cost per plain vertex: a side test per sequence and detector
(:func:`reaches`, straylight.engine.specular_reach: P and z on the air sides of the first and last lens
faces, P facing the first; it refuses only rows the checks refuse, so the numbers do not depend on it),
one Newton solve for the rows it keeps (vectorised), casts only for converged solutions (k + 1 each). A singlet has 4 sequences of one
interface and 8 more of two (:func:`candidate_sequences`, before the media rule); the default estimator
set uses ``specular_nee = 3`` with ``"mirrors"``: the single reflections (what two interfaces bought on the
guide scope, at a third of the cost) and the two thick mirrors, which a vertex tries with probability
q (:func:`try_rate`; docs/engine.md, "Thick mirrors").

**Ghosts** (``specular_nee = 4`` with ``"mirrors"``, opt-in): also a singlet's two-reflection ghosts "a (T) -> b (R) ->
a (R) -> b (T)" (:func:`ghost`; a and b the two faces of one element, :func:`_one_element`), tried at the rays' first vertices only (P lit straight by the source; a tree from
any other vertex keeps the whole path), with probability :data:`GHOST_RATE`, solved by shooting on the first
vertex (straylight.engine.specular_manifold.shoot: two unknowns; the path's geometry term from the same shots).
They are tried where the reverse chains own ghost runs (:func:`chains_own_ghosts`) or the set has no chains
(:meth:`SpecularNee.ghosts_on`); where the chains' verdict turned them off, not. At the chains' points the
ghost connection, the eye chains' source connection and the walk's K lobe draws share each path by the
three-way balance heuristic: the connection keeps p_nee / (p_nee + K p_walk + p_eye) (:meth:`SpecularNee._three_way`;
p_nee = beam density x q / (A J) on the (P, omega) measure the other two use), and each of the other two keeps
its two-way weight times (K p_walk + p_eye) / (K p_walk + p_eye + p_nee) (:meth:`SpecularNee.ghost_share` for the
trees, :meth:`SpecularNee.ghost_density_at_ends` for the eye side), p_nee re-solved for the path and taken where
the solution is the path's own. Flat detectors only there (the chains' end points keep z, not its normal).
Measured and why not in the default set: docs/engine.md, "Ghost connections".
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from geometry.analytic import Conic
from materials.mueller import apply_interface_mueller, rotate_stokes, s_vector
from materials.smooth import Dielectric
from straylight.engine import specular_manifold as manifold
from straylight.engine import specular_reach as reach
from straylight.engine.capabilities import Capability
from straylight.engine.interactions.brdf_scatter import LocalFrames
from straylight.engine.interactions.registry import parts_with
from straylight.engine.interactions.scatter_polarization import arriving
from straylight.engine.material_groups import brdf_and_pdf, by_material
from straylight.engine.ray_batch import EVENT_DETECTOR, EVENT_SCATTER, EVENT_SOURCE, EVENT_SPECULAR
from straylight.engine.reverse_chain import _beam_footprint, _flat_normal, beam_density, scatter_ends
from straylight.engine.roles import ROLE_SURFACE
from straylight.engine.surface_geometry import SELF_HIT_MM, branch_coefficients, cast_branches, side_material
from straylight.paths import mix_key
from straylight.engine.vec3 import take_rows
from straylight.rng import check_seed, chunk_stream_uniforms

MAX_INTERFACES = 4
#: the most probability q with which a vertex tries the thick-mirror sequences (:func:`thick_mirror`; one
#: uniform per vertex): q = THICK_MIRROR_RATE min(1, w / w0) with w the vertex's weight and w0 the start
#: weight (:func:`try_rate`). Their solves cost ~5x a reflection's, their paths carry ~1 % of the light
#: and most vertices (deep in the walk) carry little of it
THICK_MIRROR_RATE = 0.25
TRY_STREAM = 0x544D4952  # third entropy word of the draws that decide whether a vertex tries them ("TMIR")
SAME_DIRECTION_COS = 1.0 - 1e-9  # a re-solved path is the tree's own when omega agrees this well
#: a ghost solved by Newton's method (where the compiled shots do not know a surface, :func:`_shoot`: four vertices
#: from the unfolded straight line, a far start) stops after manifold.GIVE_UP_AFTER iterations only while its
#: residual is above this (the solver's own 1e-4 gave up on 6 of 2705 ghost paths the split trees had found from
#: beam-lit tube points, guide scope at 45 deg; with 1e-2 all 6 converge within the 20 iterations, to the tree's
#: own path)
GHOST_GIVE_UP_RESIDUAL = 1e-2
#: the probability with which a first vertex tries the ghosts (one uniform per vertex, the thick mirrors' stream)
GHOST_RATE = 1.0


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


@dataclass(frozen=True)
class Sequence:
    """One candidate interface sequence: the parts in the light's order, reflection (True) or
    transmission at each, and the solver's vertices (surfaces and indices)."""

    parts: tuple
    reflect: tuple
    vertices: tuple

    @property
    def k(self) -> int:
        return len(self.parts)

    @cached_property
    def sampled(self) -> bool:
        """Whether a vertex tries this sequence only with its probability q (:func:`try_rate`; a thick
        mirror), else always (q = 1)."""
        return thick_mirror(self)

    @cached_property
    def ghost(self) -> bool:
        """Whether this sequence is a two-reflection ghost (:func:`ghost`): tried only at the rays' first
        vertices, with :data:`GHOST_GIVE_UP_RESIDUAL`."""
        return ghost(self)


    def codes(self) -> np.ndarray:
        return np.array([p * 4 + EVENT_SPECULAR for p in self.parts], dtype=np.int64)

    @cached_property
    def ends(self) -> tuple:
        """((side test, air side) of the first vertex, the same of the last): where P and z must lie
        (straylight.engine.specular_reach; None where it does not say)."""
        out = []
        for vtx in (self.vertices[0], self.vertices[-1]):
            side, test = reach.air_side(vtx), reach.side_test(vtx.surface)
            out.append(None if side is None or test is None else (test, side))
        return tuple(out)

    @cached_property
    def aperture_ball(self) -> tuple | None:
        """(centre, radius) of a ball holding the first interface's clear aperture (None: not known)."""
        test = reach.side_test(self.vertices[0].surface)
        return None if test is None else reach.aperture_ball(test)


def chains_own_ghosts(states) -> bool:
    """Whether the batch's reverse chains (``states``: the strategy states) count runs of a ghost's four
    interfaces and two reflections from the points they own: the ghosts then join them there (three-way
    balance), and the lobe draws keep their share of those paths."""
    rc = states.get("reverse_chain")
    return rc is not None and rc.k_max >= 4 and rc.r_max >= 2


def try_rate(weight_w, w0: float) -> np.ndarray:
    """q (m,): the probability with which vertices of weight ``weight_w`` (start weight ``w0``) try the
    sampled sequences, :data:`THICK_MIRROR_RATE` min(1, w / w0). A connection counts over q and its
    balance weight is over the density q p_nee (one-sample MIS with an expected q samples; the split
    trees' share uses the same q): unbiased for any q > 0 that depends on the vertex only. A connection's
    value w f cos T / (q p_nee + p_walk) <= (w / q) f cos T A J: with q proportional to w (below w0) the
    factor w / q is w0 / THICK_MIRROR_RATE whatever the vertex's weight."""
    return THICK_MIRROR_RATE * np.minimum(1.0, np.asarray(weight_w, dtype=np.float64) / w0)


def reaches(seq: Sequence, p, n_p, z) -> np.ndarray:
    """(m,) bool: the rows whose P (m, 3) can lie on the air side of the sequence's first interface, whose
    facing side (normal ``n_p``) sees some point of that interface's aperture, and whose z (m, 3) can lie
    on the air side its last one leaves into (straylight.engine.specular_reach). The rows it refuses
    are rows :func:`connect`'s checks refuse: a part of the deterministic rule, run by the connections
    and by the split trees' shares alike."""
    ok = np.ones(len(p), dtype=bool)
    for end, q in zip(seq.ends, (p, z)):
        if end is not None:
            ok &= reach.may_lie(end[0], end[1], q)
    if seq.aperture_ball is not None:
        ok &= reach.may_face(p, n_p, *seq.aperture_ball)
    return ok


def reaches_ball(seq: Sequence, centre_mm, radius_mm: float) -> bool:
    """Whether any point within ``radius_mm`` of ``centre_mm`` (a detector's bounding ball) can lie on the
    air side the sequence's last interface leaves into (False: :func:`reaches` refuses every z there)."""
    end = seq.ends[1]
    return end is None or bool(reach.may_lie(end[0], end[1], np.asarray(centre_mm, float)[None, :], radius_mm)[0])


def detector_ball(det) -> tuple:
    """(centre, radius) of a ball holding every point of a detector (straylight.detectors.DetectorGeometry):
    its exact disk, if any, and its triangles."""
    pts = np.asarray(det.triangles_mm, dtype=np.float64).reshape(-1, 3)
    disk = getattr(det, "disk", None)
    centre = pts.mean(axis=0) if disk is None else np.asarray(disk.centre_mm, dtype=np.float64)
    radius = float(np.linalg.norm(pts - centre, axis=1).max())
    if disk is not None:
        radius = max(radius, float(np.sqrt(disk.r2_out)))
    return centre, radius * (1.0 + 1e-9) + 1e-9


def _eta(spec, part: int, front: bool) -> float:
    """n_incident / n_transmitted for light arriving on ``front`` of ``part`` (1 where it does not transmit)."""
    mat = int(side_material(spec, np.array([part]), np.array([front]))[0])
    model = spec.materials[mat] if mat >= 0 else None
    coef = None if model is None else getattr(model, "smooth_coefficients", lambda *a, **k: None)(np.array([1.0]),
                                                                                              back=not front)
    return 1.0 if coef is None else float(np.real(coef.eta[0]))


def _medium(spec, part: int) -> int:
    """The medium behind ``part`` (its back side): its material index when the material transmits (a
    dielectric's back is its glass), else -1 (air on both sides)."""
    mat = int(spec.part_material[part])
    model = spec.materials[mat] if mat >= 0 else None
    smooth = getattr(model, "smooth", None)
    return mat if isinstance(smooth, Dielectric) else -1


def interface_parts(spec, splits) -> list:
    """Parts it may connect through: the kind declares DELTA_CHAIN and the part has a conic surface."""
    surfaces = spec.part_surfaces or ()
    return [p for p in np.flatnonzero(splits) if p < len(surfaces) and isinstance(surfaces[p], Conic)]


def thick_mirror(seq: Sequence) -> bool:
    """Whether ``seq`` is a thick mirror "a (T) -> b (R) -> a (T)": light enters a face, reflects inside off
    another and leaves through the first (a singlet's: from the back, or from the front)."""
    return seq.k == 3 and seq.reflect == (False, True, False) and seq.parts[0] == seq.parts[2] != seq.parts[1]


def ghost(seq: Sequence) -> bool:
    """Whether ``seq`` is a two-reflection ghost "a (T) -> b (R) -> a (R) -> b (T)": light enters a face, reflects
    inside off the other, back off the first, and leaves through the other (a singlet's ghost)."""
    return seq.k == 4 and seq.reflect == (False, True, True, False) and seq.parts[0] == seq.parts[2] \
        and seq.parts[1] == seq.parts[3] and seq.parts[0] != seq.parts[1]


def candidate_sequences(spec, splits, max_k: int = MAX_INTERFACES, which: str = "all") -> list:
    """Every sequence of 1..max_k reflections and transmissions over :func:`interface_parts` (no part
    twice in a row: a convex or flat surface cannot be met twice in a row, and a concave one rarely);
    ``which`` = "mirrors" (``EstimatorOptions.specular_nee_sequences``) keeps only the single reflections,
    the :func:`thick_mirror` sequences and (``max_k`` 4) the :func:`ghost` sequences."""
    parts = interface_parts(spec, splits)
    surf = spec.part_surfaces
    vert = {(p, r): manifold.Vertex(surf[p], r, _eta(spec, p, True), _eta(spec, p, False), -1, _medium(spec, p))
            for p in parts for r in (True, False)}
    out: list[Sequence] = []
    chains: list[list[tuple]] = [[]]
    for _ in range(max_k):
        chains = [c + [(p, r)] for c in chains for p in parts for r in (True, False) if not c or c[-1][0] != p]
        out.extend(Sequence(tuple(int(p) for p, _ in c), tuple(r for _, r in c), tuple(vert[x] for x in c))
                   for c in chains)
    if which == "mirrors":
        out = [seq for seq in out if (seq.k == 1 and seq.reflect[0]) or thick_mirror(seq)
               or (ghost(seq) and _one_element(surf, parts, seq.parts[0], seq.parts[1]))]
    return [seq for seq in out if _media_allow(seq)]


def _one_element(surfaces, parts, a: int, b: int) -> bool:
    """Whether faces ``a`` and ``b`` bound one element: the midpoint of their vertices lies behind both (on the
    glass side, opposite each front normal) and no other interface of ``parts`` meets the segment between the
    vertices inside its clear aperture. A ghost "a T, b R, a R, b T" through faces of two elements would cross air
    or other faces (a Cooke triplet keeps its 6 single-element ghosts of the 14 the media allow)."""
    va, vb = np.asarray(surfaces[a].vertex_mm, float), np.asarray(surfaces[b].vertex_mm, float)
    mid = 0.5 * (va + vb)
    for f, v in ((a, va), (b, vb)):
        front = -float(surfaces[f].front_sign()) * np.asarray(surfaces[f].axis, float)  # the front normal at the vertex
        if float((mid - v) @ front) >= 0.0:
            return False
    for c in parts:
        if c in (a, b):
            continue
        vc, axis = np.asarray(surfaces[c].vertex_mm, float), np.asarray(surfaces[c].axis, float)
        denom = float((vb - va) @ axis)
        if abs(denom) < 1e-12:
            continue
        t = float((vc - va) @ axis) / denom
        if 0.0 < t < 1.0:
            cross = va + t * (vb - va)
            if np.linalg.norm(cross - vc) <= float(getattr(surfaces[c], "outer_radius_mm", np.inf)):
                return False
    return True


def _media_allow(seq: Sequence) -> bool:
    """Whether some choice of arrival sides lets light start and end in the air (a singlet keeps 4 of its
    12 sequences: a reflection off either face, both faces' reflections, and the two refractions)."""
    sides = np.array(np.meshgrid(*[[True, False]] * seq.k, indexing="ij")).reshape(seq.k, -1).T
    return bool(manifold.media_agree(seq.vertices, sides).any())


def unsupported(spec) -> str | None:
    """Why the strategy cannot run on ``spec`` (None when it can)."""
    est = spec.options.estimator
    if not interface_parts(spec, parts_with(spec, Capability.DELTA_CHAIN)):
        return "the scene has no interface with an analytic surface (conic, asphere or plane) to connect through"
    if int(est.delta_chain) < int(est.specular_nee):
        return f"it shares its paths with the split trees: it needs delta_chain >= specular_nee ({est.specular_nee})"
    if est.target_parts:
        return "its balance weights use the materials' own pdf; target sampling draws from a mixture"
    if spec.options.physics.polarization != "u":
        return "it carries the polarization of the walk's light; this trace fixes s or p"
    return None


class Connection:
    """Solved and checked paths P -> S -> z for one sequence: ``ok`` per row, the interface points
    and front normals, omega at P and the geometry term J = |d omega / d A_z|."""

    def __init__(self, ok, X, N, omega, J):
        self.ok, self.X, self.N, self.omega, self.J = ok, X, N, omega, J


def connect(spec, scene, seq: Sequence, p, n_p, z, nz, det_part: int, both_sides: bool,
            may=None) -> tuple[Connection, int]:
    """Solve the sequence between p (facing normal ``n_p``) and z (detector normal ``nz``, part
    ``det_part``) and check the path: the sides, the clear apertures, that light leaves P on its
    facing side and reaches the counted side of the detector, and that every segment, cast, meets
    exactly its intended point. Only the rows :func:`reaches` keeps are solved (``may``: its answer,
    when the caller has it). Returns the :class:`Connection` and the casts made."""
    m = len(p)
    may = reaches(seq, p, n_p, z) if may is None else may
    shot = _shoot(seq, p, z, nz, may) if seq.ghost else None
    sol = _solve(seq, p, z, may) if shot is None else shot.solution
    ok = sol.ok.copy()
    J, omega = np.zeros(m), np.zeros((m, 3))
    g = np.flatnonzero(ok)
    if len(g):
        sub = manifold.Solution(sol.x[g], sol.X[g], sol.N[g], ok[g])
        ok[g] = manifold.side_checks(seq.vertices, sub, p[g], z[g])
        g = g[ok[g]]
    if len(g) and shot is not None:  # the shots' own geometry term
        J[g], omega[g] = shot.J[g], shot.omega[g]
    elif len(g):
        sub = manifold.Solution(sol.x[g], sol.X[g], sol.N[g], ok[g])
        J[g], omega[g] = manifold.geometry_term(seq.vertices, sub, p[g], z[g], nz[g])
    ok &= (_dot(omega, n_p) > 0) & (J > 0) & np.isfinite(J)
    last = np.where(ok[:, None], z - sol.X[:, -1], 1.0)
    arrive = last / np.linalg.norm(last, axis=1)[:, None]
    ok &= (_dot(arrive, nz) < 0) if not both_sides else (_dot(arrive, nz) != 0)
    casts = 0
    g = np.flatnonzero(ok)
    eps2 = 2.0 * spec.eps
    here = p[g] + eps2 * n_p[g]
    last = np.full(len(g), -1, dtype=np.int64)
    for i in range(seq.k + 1):
        if len(g) == 0:
            break
        target = z[g] if i == seq.k else sol.X[g, i]
        want = det_part if i == seq.k else seq.parts[i]
        good, n_cast = _meets(spec, scene, here, target, last, want, None if i == seq.k else seq.vertices[i].surface)
        casts += n_cast
        ok[g[~good]] = False
        g, last = g[good], np.full(int(good.sum()), want, dtype=np.int64)
        if i == seq.k or len(g) == 0:
            break
        n = sol.N[g, i]
        nxt = z[g] if i == seq.k - 1 else sol.X[g, i + 1]
        side = np.where(_dot(nxt - sol.X[g, i], n) > 0, 1.0, -1.0)
        here = sol.X[g, i] + eps2 * side[:, None] * n
    return Connection(ok, sol.X, sol.N, omega, J), casts


def _runs_through(seq: Sequence, codes) -> np.ndarray:
    """(n,) bool: the runs whose first ``seq.k`` interface codes (part * 4 + event) are the sequence's parts."""
    parts = np.array(seq.parts, dtype=np.int64)
    return np.all(codes[:, :seq.k] // 4 == parts[None, :], axis=1)


def _solve(seq: Sequence, p, z, rows) -> manifold.Solution:
    """manifold.solve on the rows ``rows`` (bool), the others not converged (its rows are independent:
    the same numbers as solving them all); a ghost's with :data:`GHOST_GIVE_UP_RESIDUAL`."""
    give_up = GHOST_GIVE_UP_RESIDUAL if seq.ghost else manifold.GIVE_UP_RESIDUAL
    if rows.all():
        return manifold.solve(seq.vertices, p, z, give_up_residual=give_up)
    m = len(p)
    x = np.zeros((m, 2 * seq.k))
    X = np.full((m, seq.k, 3), np.nan)
    N = np.full((m, seq.k, 3), np.nan)
    ok = np.zeros(m, dtype=bool)
    g = np.flatnonzero(rows)
    if len(g):
        sub = manifold.solve(seq.vertices, p[g], z[g], give_up_residual=give_up)
        x[g], X[g], N[g], ok[g] = sub
    return manifold.Solution(x, X, N, ok)


def _shoot(seq: Sequence, p, z, nz, rows) -> manifold.Shot | None:
    """manifold.shoot on the rows ``rows`` (bool), the others not converged (None: a surface the compiled shots
    do not know; the Newton solve then)."""
    if rows.all():
        return manifold.shoot(seq.vertices, p, z, nz)
    m = len(p)
    g = np.flatnonzero(rows)
    sub = manifold.shoot(seq.vertices, p[g], z[g], nz[g])
    if sub is None:
        return None
    x = np.zeros((m, 2 * seq.k))
    X = np.full((m, seq.k, 3), np.nan)
    N = np.full((m, seq.k, 3), np.nan)
    ok = np.zeros(m, dtype=bool)
    J, omega, shots = np.zeros(m), np.zeros((m, 3)), np.zeros(m, np.int64)
    x[g], X[g], N[g], ok[g] = sub.solution
    J[g], omega[g], shots[g] = sub.J, sub.omega, sub.shots
    return manifold.Shot(manifold.Solution(x, X, N, ok), J, omega, shots)


def _meets(spec, scene, origin, target, last_part, want, surface) -> tuple[np.ndarray, int]:
    """Whether the segments origin -> target first meet part ``want`` (one, or one per row) at the target (on ``surface``
    refined, or on the facet for a detector), past hits on their own last part that refine back onto
    the origin (the facets of a concave surface lie in front of it: as the walk passes them,
    straylight.engine.surface_geometry.refine_on_surfaces)."""
    vec = target - origin
    length = np.linalg.norm(vec, axis=1)
    d = np.ascontiguousarray(vec / length[:, None])
    tol = 1e-6 * length + 4.0 * spec.eps
    good = np.zeros(len(origin), dtype=bool)
    start = np.zeros(len(origin))  # distance already passed
    live = np.arange(len(origin))
    casts = 0
    surfaces = spec.part_surfaces or ()
    for _ in range(3):
        if len(live) == 0:
            break
        o = np.ascontiguousarray(origin[live] + start[live, None] * d[live])
        h = cast_branches(spec, scene, o, d[live])
        casts += len(live)
        rows = live[h.hit]
        again = np.zeros(len(rows), dtype=bool)
        self_hit = h.part == last_part[rows]
        if self_hit.any():
            k = np.flatnonzero(self_hit)
            surf = surfaces[int(h.part[k[0]])] if int(h.part[k[0]]) < len(surfaces) else None
            if surf is not None:
                t, _n, fine = surf.refine_hits(o[h.hit[k]], d[rows[k]], h.distance_mm[k])
                again[k] = ~fine | (t + start[rows[k]] < SELF_HIT_MM + 4.0 * spec.eps)
        hit_want = (h.part == (want if np.ndim(want) == 0 else want[rows])) & ~again
        sel = np.flatnonzero(hit_want)
        if len(sel):
            rr = rows[sel]
            if surface is None:
                t = h.distance_mm[sel]
                fine = np.ones(len(sel), dtype=bool)
            else:
                t, _n, fine = surface.refine_hits(o[h.hit[sel]], d[rr], h.distance_mm[sel])
            good[rr] = fine & (np.abs(start[rr] + t - length[rr]) <= tol[rr])
        nxt = rows[again]
        start[nxt] += h.distance_mm[again] + 2.0 * spec.eps
        live = nxt
    return good, casts


def chain_throughput(spec, seq: Sequence, p, X, N, z, S, e1) -> np.ndarray:
    """(M_k ... M_1 S)_0 x bulk along the solved path: S (m, 4) the Stokes vector leaving p in the frame
    ``e1`` (as the split trees carry it from their root, straylight.engine.delta_chain)."""
    m = len(p)
    T = np.ones(m)
    S = S.copy()
    prev = p
    for i in range(seq.k):
        vec = X[:, i] - prev
        dist = np.linalg.norm(vec, axis=1)
        d = vec / np.where(dist > 0, dist, 1.0)[:, None]
        n = N[:, i]
        front = _dot(d, n) < 0
        facing = np.where(front[:, None], n, -n)
        part = np.full(m, seq.parts[i], dtype=np.int64)
        rs, rp, ts, tp, _cos_t, _eta, bulk = branch_coefficients(spec, part, front, d, facing, dist)
        s = s_vector(d, facing)
        S = rotate_stokes(S, e1, s, d)
        a_s, a_p = (rs, rp) if seq.reflect[i] else (ts, tp)
        So = apply_interface_mueller(a_s, a_p, S)
        T = T * So[:, 0] * bulk
        S = So / np.where(So[:, 0] > 0, So[:, 0], 1.0)[:, None]
        e1 = s
        prev = X[:, i]
    return T


class SpecularNee:
    """Per batch: the candidate sequences, and per ray the last plain scatter vertex it left (for the
    split trees' shares)."""

    def __init__(self, ctx, splits):
        spec, scene = ctx.spec, ctx.scene
        est = spec.options.estimator
        self.max_k = int(est.specular_nee)  # interfaces per connection, 1..MAX_INTERFACES
        self.seqs = candidate_sequences(spec, splits, self.max_k, est.specular_nee_sequences)
        self.end_material = scatter_ends(spec)
        self.splits = splits
        n = ctx.n_rays
        self.depth = np.full(n, -1, dtype=np.int64)  # depth of the ray's vertex P (-1: none of ours)
        self.point = np.zeros((n, 3))
        self.normal = np.zeros((n, 3))
        self.chain_k = np.zeros(n, dtype=np.int64)  # runs up to this length are the reverse chains'
        self.pdf = np.zeros(n)  # the walk's pdf of the direction it drew at P
        self.rate = np.zeros(n)  # q at P (try_rate)
        self.first = np.zeros(n, dtype=bool)  # P is the ray's first vertex (lit by the source)
        self.w0 = float(ctx.start_weight_w)
        # the tries' uniforms: an own stream per chunk (the walk's random numbers stay those without them)
        self.any_sampled = any(seq.sampled or seq.ghost for seq in self.seqs)
        self.seed = check_seed(spec.seed)
        self.first_chunk = int(spec.chunk_offset) + int(ctx.first_chunk)
        self._gens: dict = {}
        self.det_area = np.array([g.area_mm2 for g in scene.detectors], dtype=np.float64)
        self.det_parts = np.asarray(scene.det_parts, dtype=np.int64)
        # per detector the sequences whose last interface can leave toward some point of it (reaches_ball)
        self.seqs_to = [[seq for seq in self.seqs if reaches_ball(seq, *detector_ball(det))] for det in scene.detectors]
        self.both = spec.options.output.detector_sides == "both"
        self.path_depth = int(spec.options.output.path_depth)
        self.shadow_rays = 0
        self.has_ghosts = any(seq.ghost for seq in self.seqs)
        self.no_chains = int(est.reverse_chain) <= 0  # (the set has no eye chains: not turned off by their verdict)
        # per detector its one normal (flat) or None: the ghosts join the eye chains' points on flat detectors only
        # (the chains' end points keep z, not its normal)
        self.flat = [_flat_normal(det) for det in scene.detectors]
        self.footprint = _beam_footprint(spec.sources[0]) if self.has_ghosts and len(spec.sources) == 1 else None

    # ------------------------------------------------------------------ the walk's vertices

    def vertices(self, event, cont):
        """The continuing hits that are plain scatter vertices, and the run length the reverse chains
        own from each (0: none)."""
        spec, hit, rays = event.spec, event.hits, event.rays
        part = hit.part[cont].astype(np.int64)
        mat = spec.part_material[part]
        plain = (spec.part_roles[part] == ROLE_SURFACE) & ~self.splits[part] & self.end_material[mat] \
            & (rays.weight_w[cont] > 0)
        rows = cont[plain]
        chain_k = np.zeros(len(rows), dtype=np.int64)
        rc = event.states.get("reverse_chain")
        if rc is not None:
            chain_k = np.where(rc.pred[rays.ray[rows]], rc.k_max, 0)
        return rows, chain_k

    def after_hits(self, event, cont, column: int) -> None:
        """At the plain scatter vertices among the continuing hits (before the interactions change the
        rays' polarization states): the connections through every candidate sequence."""
        rays = event.rays
        rows, chain_k = self.vertices(event, cont)
        mine = chain_k < self.max_k
        if self.ghosts_on(event.states) and self.footprint is not None:  # the ghosts also at the chains' first vertices
            mine |= rays.last_event[rows] == EVENT_SOURCE
        rows, chain_k = rows[mine], chain_k[mine]
        if len(rows) == 0:
            return
        r = rays.ray[rows]
        self.depth[r] = rays.depth[rows]
        self.point[r] = take_rows(event.hits.point_mm, rows)
        self.normal[r] = take_rows(event.hits.facing_normal, rows)
        self.chain_k[r] = chain_k
        self.rate[r] = try_rate(rays.weight_w[rows], self.w0)
        self.first[r] = rays.last_event[rows] == EVENT_SOURCE
        u_try = chunk_stream_uniforms(self._gens, self.seed, self.first_chunk, TRY_STREAM, r, 1)[:, 0] \
            if self.any_sampled else None
        self._connect(event, rows, chain_k, column, u_try)

    def after_interactions(self, event, cont, out) -> None:
        r = event.rays.ray[cont]
        ours = self.depth[r] == event.rays.depth[cont]
        self.pdf[r[ours]] = out.pdf_per_sr[ours]

    def _connect(self, event, rows, chain_k, column, u_try):
        spec, scene, rays, hit = event.spec, event.scene, event.rays, event.hits
        U = event.uniforms
        p, n_p = take_rows(hit.point_mm, rows), take_rows(hit.facing_normal, rows)
        # per detector its points z, and per sequence the rows it may connect (reaches): the rows none
        # may are left before the frames and the polarization (every step below is row by row)
        todo, need = [], np.zeros(len(rows), dtype=bool)
        q = self.rate[rays.ray[rows]]  # the sampled sequences (thick mirrors) are tried where u_try < q
        first = self.first[rays.ray[rows]]  # the ghosts are tried at the rays' first vertices only
        ghosts = self.ghosts_on(event.states)
        for j, det in enumerate(scene.detectors):
            z, nz = det.sample(np.ascontiguousarray(U[rows, column + 3 * j:column + 3 * j + 3]))
            for seq in self.seqs_to[j]:
                if seq.ghost:  # at first vertices, the chains' too (three-way balance) where the detector is flat
                    if not ghosts:
                        continue
                    may = first & ((chain_k == 0) | (self.flat[j] is not None)) & reaches(seq, p, n_p, z) \
                        & (u_try < GHOST_RATE)
                else:
                    may = (chain_k < seq.k) & reaches(seq, p, n_p, z)
                if seq.sampled:
                    may &= u_try < q
                if may.any():
                    todo.append((j, seq, may, z, nz))
                    need |= may
        if not todo:
            return
        sub = np.flatnonzero(need)
        rows, p, n_p = rows[sub], p[sub], n_p[sub]
        verts = np.ascontiguousarray(rows)
        frame = LocalFrames(*event.kernels.frames(verts, rays.direction, hit.facing_normal, hit.part,
                                                  spec.part_material, event.uniforms))  # the walk's kernel (same bits)
        arr = arriving(event, verts, frame)
        evaluate = _unpolarized(spec, frame.material)
        q = q[sub]
        for j, seq, may, z, nz in todo:
            z, nz, may = z[sub], nz[sub], may[sub]
            area = self.det_area[j]
            pos = np.flatnonzero(may)
            con, casts = connect(spec, scene, seq, p[pos], n_p[pos], z[pos], nz[pos], int(self.det_parts[j]),
                                 self.both, may=np.ones(len(pos), dtype=bool))
            self.shadow_rays += casts
            g = np.flatnonzero(con.ok)
            if len(g) == 0:
                continue
            at = pos[g]
            omega = con.omega[g]
            wo_local = np.stack([_dot(omega, take_rows(frame.tangent, at)), _dot(omega, take_rows(frame.bitangent, at)),
                                 _dot(omega, n_p[at])], axis=1)
            f, pdf = evaluate(take_rows(frame.wi_local, at), wo_local, at)
            S = np.zeros((len(g), 4))
            S[:, 0] = 1.0
            e1 = s_vector(omega, n_p[at])
            if arr is not None:  # the walk's polarized scatter: f = M[0] . S = ratio x f_u, and M S carried on
                ratio, use, S_out, e1_out = arr.scattered(event, verts, omega, subset=at)
                f = f * ratio
                S[use], e1[use] = S_out / S_out[:, :1], e1_out  # M S, normalised as the walk stores it
            T = chain_throughput(spec, seq, p[at], con.X[g], con.N[g], z[at], S, e1)
            J = con.J[g]
            rate = q[at] if seq.sampled else (GHOST_RATE if seq.ghost else 1.0)
            p_nee = rate / (area * J)
            mis = p_nee / (p_nee + pdf)
            if seq.ghost:
                owned = chain_k[sub][at] > 0
                if owned.any():  # against the walk's K draws and the eye chains (module doc, "Ghosts")
                    o = np.flatnonzero(owned)
                    arrival = z[at[o]] - con.X[g[o], -1]
                    arrival /= np.linalg.norm(arrival, axis=1)[:, None]
                    mis[o] = self._three_way(event, rows[at[o]], j, seq, omega[o], n_p[at[o]], arrival, pdf[o],
                                             p_nee[o])
            value = rays.weight_w[rows[at]] * f * _dot(omega, n_p[at]) * T * J * area * mis / rate
            keep = np.flatnonzero(value > 0)
            if len(keep):
                self._tally(event, rows[at[keep]], j, seq, z[at[keep]], value[keep])

    def _tally(self, event, rows, j, seq, z, value):
        rays, hit = event.rays, event.hits
        r = rays.ray[rows]
        part = hit.part[rows].astype(np.int64)
        event.tallies.add(event.rows.detector_nee + int(j), r, value)
        event.tallies.subtract(event.rows.nee_exchange + part, r, value)
        keys = events = None
        depth = rays.depth[rows]
        if event.settings.record_paths:
            code_p = part * 4 + EVENT_SCATTER
            h = mix_key(rays.path_key[rows], code_p)
            codes = seq.codes()
            for c in codes:
                h = mix_key(h, np.full(len(rows), c, dtype=np.int64))
            keys = mix_key(h, np.full(len(rows), int(self.det_parts[j]) * 4 + EVENT_DETECTOR, dtype=np.int64))
            events = rays.history[rows].copy()
            width = events.shape[1]
            idx = np.arange(len(rows))
            for step, c in enumerate(np.concatenate([[-1], codes])):
                at = depth + step < width
                events[idx[at], (depth + step)[at]] = code_p[at] if step == 0 else c
        event.records.add(int(j), r, z, value, keys, events, depth + 1 + seq.k)

    def _same_path(self, spec, scene, seq, p, n_p, z, nz, omega, detector: int) -> tuple:
        """Re-solve (p, z) through ``seq`` as :meth:`_connect` does: the rows whose solution is the path that leaves
        p along ``omega`` (bool), and their geometry terms |d omega / dA_z|."""
        con, casts = connect(spec, scene, seq, p, n_p, z, nz, int(self.det_parts[detector]), self.both)
        self.shadow_rays += casts
        match = con.ok & (_dot(con.omega, omega) > SAME_DIRECTION_COS)
        return match, con.J[match]

    def ghosts_on(self, states) -> bool:
        """Whether it tries its ghosts in this batch (``states``: the strategy states): where the reverse chains
        own ghost runs (:func:`chains_own_ghosts`; joined to them by the three-way balance), or in a set without
        eye chains; not where the chains' verdict turned them off (the ghosts' family carries nothing there,
        straylight.engine.reverse_chain, "Where the chains pay") or they stop short of a ghost's runs."""
        return self.has_ghosts and (self.no_chains or chains_own_ghosts(states))

    def ghosts_shared(self, states) -> bool:
        """Whether its ghosts join the reverse chains at the points they own in this batch (:func:`chains_own_ghosts`)."""
        return self.has_ghosts and chains_own_ghosts(states)

    def _three_way(self, event, rows, j, seq, omega, n_p, arrival, pdf, p_nee) -> np.ndarray:
        """The ghost connection's balance weight at the eye chains' first vertices ``rows``: p_nee / (p_nee +
        K p_walk + p_eye) on the (P, omega) measure (the beam's area density times each side's direction
        density; K the walk's lobe draws there, straylight.engine.tree_split)."""
        rc = event.states["reverse_chain"]
        beam = beam_density(self.w0, event.rays.weight_w[rows], take_rows(event.rays.direction, rows), n_p,
                            self.footprint)
        draws = np.ones(len(rows))
        split = getattr(event.states.get("delta_chain"), "lobe_split", None)
        if split is not None:
            part = event.hits.part[rows].astype(np.int64)
            codes = np.tile(seq.codes(), (len(rows), 1))
            draws = split.draws_at_source_points(event.states, event.spec.part_material[part], part,
                                                 np.full(len(rows), seq.k), codes, int(j))
        p_eye = rc.eye_density(event, np.ones(len(rows), dtype=bool), _dot(omega, n_p), int(j), arrival)
        full = beam * p_nee
        total = full + beam * pdf * draws + p_eye
        return np.where(total > 0, full / np.where(total > 0, total, 1.0), 0.0)

    def ghost_density_at_ends(self, spec, scene, e, g, p_area) -> np.ndarray:
        """(len(g),) the ghost connections' density of the eye chains' source-connected end points ``e`` rows
        ``g`` (P lit straight by the beam, walk area density ``p_area``): p_area q / (A |d omega / dA_z|) where
        the chain is one of this estimator's ghosts and the re-solved path (P, the chain's z) is the chain's
        own, else 0 (the eye side's balance weight adds it to the walk's)."""
        out = np.zeros(len(g))
        for j, det in enumerate(scene.detectors):
            if self.flat[j] is None:
                continue
            for seq in self.seqs_to[j]:
                if not seq.ghost:
                    continue
                at = np.flatnonzero((e.detector[g] == j) & (e.k[g] == seq.k) & _runs_through(seq, e.codes[g]))
                if len(at) == 0:
                    continue
                rows = g[at]
                match, J = self._same_path(spec, scene, seq, e.point[rows], e.normal[rows], e.z[rows],
                                           np.tile(self.flat[j], (len(at), 1)), e.omega[rows], j)
                out[at[match]] = p_area[at[match]] * GHOST_RATE / (self.det_area[j] * J)
        return out

    def ghost_share(self, event, r, owned, detector: int, z, nz, codes, k, omega, arrival, p_walk, beam) -> np.ndarray:
        """The factor (p_walk + p_eye) / (p_walk + p_eye + p_nee) split-tree branches of rays ``r`` keep where
        their path (``k`` interfaces ``codes`` into ``detector`` at ``z``, leaving P along ``omega``, arriving
        along ``arrival``, walk density ``p_walk`` with its draws, ``beam`` the area density of P) is a ghost
        this estimator makes from P at the eye chains' vertex (``owned``: the caller's rows whose P is the vertex
        this estimator recorded, owned by the chains): the two-way weights against the eye chains times it are
        the three-way balance heuristic; 1 elsewhere."""
        out = np.ones(len(r))
        if not self.has_ghosts or self.flat[detector] is None:
            return out
        g = np.flatnonzero(owned & self.first[r] & (k == 4))
        if len(g) == 0:
            return out
        p_nee = np.zeros(len(r))
        for seq in self.seqs_to[detector]:
            if not seq.ghost:
                continue
            at = g[_runs_through(seq, codes[g])]
            if len(at) == 0:
                continue
            ri = r[at]
            match, J = self._same_path(event.spec, event.scene, seq, self.point[ri], self.normal[ri], z[at], nz[at],
                                       omega[at], detector)
            p_nee[at[match]] = beam[at[match]] * GHOST_RATE / (self.det_area[detector] * J)
        h = np.flatnonzero(p_nee > 0)
        if len(h) == 0:
            return out
        rc = event.states["reverse_chain"]
        p_eye = rc.eye_density(event, np.ones(len(h), dtype=bool), _dot(omega[h], self.normal[r[h]]), detector,
                               arrival[h])
        rest = p_walk[h] + p_eye
        out[h] = rest / (rest + p_nee[h])
        return out

    # ------------------------------------------------------------------ the split trees' side

    def covers(self, k, codes, detector: int, states) -> np.ndarray:
        """(n,) bool: the split-tree branches (``k`` interfaces, ``codes``) reaching ``detector`` whose path
        this estimator may also make: one of its sequences for that detector has their parts (a superset
        of the branches :meth:`branch_share` shares; the further lobe draws of straylight.engine.tree_split
        leave these to the walk's own tree). The ghosts only where it tries them (:meth:`ghosts_on`) and the
        chains do not own them (``states``: the batch's strategy states): where they do, the ghosts join the
        chains and the draws by the three-way balance (:meth:`ghost_share`)."""
        out = np.zeros(len(k), dtype=bool)
        own_ghosts = not self.ghosts_on(states) or chains_own_ghosts(states)
        for seq in self.seqs_to[detector]:
            if own_ghosts and seq.ghost:
                continue
            out |= (k == seq.k) & _runs_through(seq, codes)
        return out

    def branch_share(self, event, rows, detector: int, z, nz, codes, k) -> np.ndarray:
        """The share split-tree branches keep (rooted at the interface hits ``rows``, reaching
        ``detector`` at ``z`` with triangle normals ``nz`` after ``k`` interfaces ``codes``): p_walk /
        (p_walk + p_nee) where this estimator makes the same path (module doc), else 1."""
        rays = event.rays
        out = np.ones(len(rows))
        r = rays.ray[rows]
        ours = (self.depth[r] >= 0) & (rays.depth[rows] == self.depth[r] + 1) & (k <= self.max_k) \
            & (k > self.chain_k[r])
        g = np.flatnonzero(ours)
        if len(g) == 0:
            return out
        area = self.det_area[detector]
        p_nee = np.zeros(len(rows))
        ghosts = self.ghosts_on(event.states)
        for seq in self.seqs_to[detector]:  # the others reach no point of it (the same rule as connect's)
            if seq.ghost and not ghosts:
                continue
            at = g[(k[g] == seq.k) & _runs_through(seq, codes[g])]
            if len(at) == 0:
                continue
            ri = r[at]
            match, J = self._same_path(event.spec, event.scene, seq, self.point[ri], self.normal[ri], z[at], nz[at],
                                       rays.direction[rows[at]], detector)
            if seq.ghost:  # (made at the first vertices only: elsewhere the tree keeps the whole path)
                J = J[self.first[ri[match]]]
                match &= self.first[ri]
            rate = self.rate[ri[match]] if seq.sampled else (GHOST_RATE if seq.ghost else 1.0)
            p_nee[at[match]] = rate / (area * J)
        walk = self.pdf[r]
        total = walk + p_nee
        share = np.where(total > 0, walk / np.where(total > 0, total, 1.0), 1.0)
        return np.where(p_nee > 0, share, out)


def _unpolarized(spec, material):
    """``evaluate(wi, wo, vertex)`` of unpolarized light: the materials' BRDF and pdf."""

    def evaluate(wi, wo_local, vertex):
        f = np.empty(len(vertex))
        pdf = np.empty(len(vertex))
        for rows, (fv, pv) in by_material(spec.materials, material[vertex], lambda model, rows:
                brdf_and_pdf(model, wi[rows], wo_local[rows], "u")):
            f[rows] = fv
            pdf[rows] = pv
        return f, pdf

    return evaluate
