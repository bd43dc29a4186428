"""The ghost table of the lenses in a scene (CONTRACTS 8.4), by forced-sequence tracing.

A *ghost* is a path that reflects an even number of times at Fresnel interfaces (``dielectric``
parts, coated or not) where the design transmits. The design path, the *nominal* sequence, is found
first: source rays are followed taking the likelier branch at every interface (transmission through
glass, reflection at a mirror) until they reach the detector; of the sequences that pass through at
least one interface, the one that carries the most power is the nominal one (a lens: every surface in
turn; a telescope: its mirrors too).

Each ghost is then a sequence derived from the nominal one by reflections at positions
``r1 > r2 < r3 > ...`` (the ray reflects forward at r1, runs back through the nominal parts to r2,
reflects again and runs forward...): for order 2 every pair of interfaces, C(n, 2) ghosts for n
transmitting interfaces (15 for a Cooke triplet, 45 for a 10-surface double Gauss), as OpticStudio's
ghost focus generator and FRED's ghost-path listing count them.

Every source ray of a ghost is traced through exactly that sequence of parts (a ray whose next hit is
another part, or outside the clear aperture, is blocked: vignetting and the mechanics are the
scene's own). At each interface the ray's weight is multiplied by the reflected or transmitted power
of its Stokes vector, with the same Fresnel (and thin-film) amplitudes, Mueller matrices and bulk
absorption as the engine's walk (``optical_surface``, ``delta_chain``): the weight is the exact
expectation over the walk's branch choices along that sequence, so only the sampling of the source
is random. Estimator per ghost: the mean of the per-ray powers, its standard error the sample
standard deviation over sqrt(rays); rays are added in batches until the relative error reaches the
target, or the ghost is below ``min_fraction`` of the nominal power, or the ray budget is spent.

At the detector each ghost also gives
- ``focus_mm``: where its ray bundle is narrowest, along the direction light travels at the detector
  (the weighted least-squares waist: ``s* = -cov(q, u) / var(u)`` for transverse positions q and
  slopes u); > 0 beyond the detector, < 0 before it, null for a collimated ghost;
- ``radius_mm``: the power-weighted RMS radius of its spot on the detector about its centroid;
- ``peak_ratio``: its peak irradiance over the nominal image's, both binned on the same grid of
  ``MAP_BINS`` x ``MAP_BINS`` cells over the detector's disk and averaged over ``PEAK_CELLS`` x
  ``PEAK_CELLS`` cells, or more where a block of that size holds too few rays to know its mean to
  ``PEAK_REL_ERROR`` (:func:`peak_estimate`): the largest of many noisy block means measures the noise
  (a singlet's defocused ghost, 9 rays a cell: 3.7x its paraxial peak), so the block is found with one
  half of the batches and its irradiance read from the other half.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from time import monotonic
from typing import TYPE_CHECKING, Any

import numpy as np

from materials.mueller import apply_interface_mueller, rotate_stokes, s_vector
from materials.smooth import reflect, refract

if TYPE_CHECKING:
    from straylight.intersect import Intersector
    from straylight.sources import Source

MAP_BINS = 64
PEAK_CELLS = 3  # the peak irradiance is the largest mean over PEAK_CELLS x PEAK_CELLS cells (or more: peak_estimate)
#: the relative standard error a peak's block must reach before a larger block is tried (peak_estimate)
PEAK_REL_ERROR = 0.05
#: the block sizes peak_estimate tries, in cells across, smallest first
PEAK_BLOCKS = (PEAK_CELLS, 5, 9, 17, 33)
EPS_MM = 1e-6  # the smallest offset off a surface; a scene's own is scene_epsilon's (float32 ulps of its extent)
SELF_HIT_MM = 1e-6
MAX_NOMINAL_STEPS = 200
NOMINAL_MIN_ARRIVALS = 20  # rays through an interface onto the detector the design-path search wants to see
NOMINAL_MAX_RAYS = 300_000  # ... looking with up to this many source rays
MAX_TOTAL_RAYS = 4_000_000  # rays all the ghosts of a table share (ghost_table; 1.8e6 for a double Gauss's 45)
NOMINAL_MIN_SHARE = 0.02  # a design path carries at least this share of the strongest sequence's power
# a ghost's first LEARN_BATCHES batches are uniform over the source (more, up to LEARN_MAX_BATCHES, until
# GUIDE_MIN_HITS of their rays arrive); when fewer than GUIDE_BELOW of their rays arrive and the target is more
# than GUIDE_AFTER times their rays away, the rest is drawn from the entrance table they learn (ghost_table's Run)
LEARN_BATCHES = 2
LEARN_MAX_BATCHES = 32  # ... or more, up to this many, until GUIDE_MIN_HITS of their rays arrive
BATCH_RAYS = 4096  # rays per batch of a ghost, fewer (not below MIN_BATCH_RAYS) when two a ghost exceed the budget
MIN_BATCH_RAYS = 256
GUIDE_BELOW = 0.5
GUIDE_MIN_HITS = 16
GUIDE_AFTER = 3.0
FIRST_ROUND_SHARE = 0.5  # under --max-seconds, the part of it every ghost's first batch may take (ghost_table)
#: under ``straylight ghosts --max-seconds S``, the seconds kept back for writing the table, the maps' PNG and the
#: 3-D view (at most 0.3 S): ~1.5-3 s measured on a 19-surface lens (matplotlib's layout of nine maps)
WRITE_RESERVE_S = 3.0
#: under a cap counted from before the nominal image's trace (``started``), the part of it the ghosts get whatever
#: that trace took: a cap the nominal image alone overruns still gives every ghost its first rays where it can
MIN_GHOST_SHARE = 0.25


class GhostError(ValueError):
    """A scene the ghost analysis cannot handle (no detector, no interface, no nominal path)."""


# ---------------------------------------------------------------- the scene as the forced tracer sees it


@dataclass(eq=False)
class GhostOptics:
    """Parts, their analytic surfaces and resolved materials, one intersector, the detector and the source."""

    names: tuple
    surfaces: tuple
    models: tuple  # per part: (front model or None, back model or None)
    roles: tuple
    isect: Intersector
    tri_part: np.ndarray
    tri_normals: np.ndarray
    detector: int
    source: Source
    eps_mm: float = EPS_MM  # offset off a surface after a hit (straylight.engine.spec.scene_epsilon, as the walk's)
    field_deg: float = 0.0  # the source's turn from the scene's direction (prepare)

    def is_interface(self, p: int) -> bool:
        return self.models[p][0] is not None and getattr(self.models[p][0], "smooth", None) is not None


def prepare(rs, field_deg: float = 0.0, detector: str | None = None) -> GhostOptics:
    """The forced tracer's view of a loaded scene (``straylight.scene.load_scene``); the source turned to
    field ``field_deg`` in the meridional y-z plane (CONTRACTS 8.1: +z toward (0, sin F, cos F))."""
    from straylight.engine.spec import back_material_index, resolve_materials, scene_epsilon
    from straylight.intersect import EmbreeIntersector

    scene = rs.scene
    parts = scene.parts
    dets = [i for i, p in enumerate(parts) if p.role == "detector"]
    if detector is not None:
        name = scene.resolve(detector) if hasattr(scene, "resolve") else detector
        dets = [i for i in dets if parts[i].name == name]
        if not dets:
            raise GhostError(f"no detector part named {detector!r} in the scene")
    if not dets:
        raise GhostError("the scene has no detector part (role = \"detector\")")
    if not rs.sources:
        raise GhostError("the scene has no source")
    part_material, models = resolve_materials(scene, rs.materials)
    back = back_material_index(scene)
    per_part = []
    for i, p in enumerate(parts):
        front = models[part_material[i]] if part_material[i] >= 0 else None
        per_part.append((front, models[back[i]] if back[i] >= 0 else None))
    _has_dielectric(per_part)  # before the intersector is built (a refusal leaves no embree scene to tear down)
    tri = np.ascontiguousarray(scene.triangles_mm, dtype=np.float64)
    nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1), 1e-300)[:, None]
    src = _at_field(rs.sources[0], field_deg)
    opt = GhostOptics(tuple(p.name for p in parts), tuple(getattr(p, "surface", None) for p in parts),
                      tuple(per_part), tuple(p.role for p in parts), EmbreeIntersector(tri),
                      np.asarray(scene.triangle_part, dtype=np.int64), nrm, dets[0], src,
                      max(EPS_MM, scene_epsilon(tri)), float(field_deg))
    if field_deg and hasattr(src, "radius_mm"):
        opt.source = _covering_entrance(opt, tri)
    return opt


def _has_dielectric(models) -> None:
    """Refuse a scene with no lens or window: ``models`` per part (front, back) material models."""
    from materials.smooth import Dielectric

    if not any(isinstance(getattr(m, "smooth", None), Dielectric) for pair in models for m in pair):
        raise GhostError("the scene has no lens or window (no dielectric part: a mirror system), so no ghost")


def _at_field(source, field_deg: float):
    """The source with its direction turned by ``field_deg`` about the world x axis (+z -> (0, sin F, cos F))."""
    if not field_deg:
        return source
    if not hasattr(source, "direction"):
        raise GhostError("--field-deg needs a collimated source (a collimated_disk, as optics import writes)")
    import dataclasses

    f = math.radians(field_deg)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(f), math.sin(f)], [0.0, -math.sin(f), math.cos(f)]])
    return dataclasses.replace(source, direction=rx @ np.asarray(source.direction, float))


#: rays of the pilot that finds where light enters the lenses at a turned field (:func:`_covering_entrance`)
ENTRANCE_PILOT_RAYS = 20000
ENTRANCE_MARGIN = 1.05  # the disk's radius over the farthest entering ray's
ENTRANCE_PILOTS = 3  # looks at most, each over the disk the last one found
ENTRANCE_PILOT_FILL = 0.25  # a look in which this share of the pilot enters needs no next one


def _covering_entrance(opt: "GhostOptics", tri: np.ndarray):
    """The turned collimated disk moved and resized to cover every ray that enters the lenses at the field, at the
    scene source's irradiance (power_w x the area ratio).

    Turning the source alone leaves it where the scene had it for its own field: a wide-angle lens's beam at its
    63 deg edge crosses the source plane ~50 mm off axis, past a disk 1.1 x the largest clear aperture centred on the
    axis, so the ghosts of most of the light were never traced. Here a pilot of :data:`ENTRANCE_PILOT_RAYS` rays
    from a disk widened by tan(F) x the depth of the lens parts behind the source plane finds the rays whose first
    hit is a lens or window part (an interface met from the air); the new disk is the one about their centroid
    holding them all (out to the farthest plus the pilot's spacing, x :data:`ENTRANCE_MARGIN`), never smaller than
    the scene's own; where few entered (a small lens far behind the source), a second and third look over the disk
    the last one found. Light that first meets a barrel, a mount or nothing never reaches a ghost."""
    import dataclasses

    src: Any = opt.source  # a CollimatedDisk (prepare calls this for a source with a radius)
    lens_parts = [p for p in range(len(opt.names)) if opt.is_interface(p)]
    if not lens_parts:
        return src
    c = np.asarray(src.center_mm, float)
    n = np.asarray(src.normal, float) / np.linalg.norm(src.normal)
    d = np.asarray(src.direction, float)
    pts = tri[np.isin(opt.tri_part, lens_parts)].reshape(-1, 3)
    depth = float(np.max(np.abs((pts - c) @ n))) if len(pts) else 0.0
    cos_f = abs(float(d @ n))
    wide = float(src.radius_mm) + depth * math.sqrt(max(1.0 - cos_f * cos_f, 0.0)) / max(cos_f, 1e-6)
    centre, radius = c, wide
    for _ in range(ENTRANCE_PILOTS):
        trial = dataclasses.replace(src, center_mm=centre, radius_mm=radius)
        pilot = dataclasses.replace(opt, source=trial)
        b = emit(pilot, ENTRANCE_PILOT_RAYS, np.random.default_rng(0))
        part, _, _, _, front = next_hits(pilot, b)
        enters = (part >= 0) & front & np.isin(part, lens_parts)
        if not enters.any():
            return src
        # start points on the source plane (the rays start there), about the centroid of the entering ones, out to
        # the farthest plus the pilot's spacing (a sparse pilot's farthest ray lies up to a spacing inside the edge)
        start = b.o[enters]
        spacing = radius * math.sqrt(math.pi / ENTRANCE_PILOT_RAYS)
        new_centre = start.mean(axis=0)
        new_radius = float(np.max(np.linalg.norm(start - new_centre, axis=1))) + spacing
        if new_radius >= radius:  # the entering rays fill the pilot's disk: keep it whole
            break
        centre, radius = new_centre, new_radius
        if enters.sum() >= ENTRANCE_PILOT_FILL * ENTRANCE_PILOT_RAYS:  # dense enough: no second look
            break
    radius = max(ENTRANCE_MARGIN * radius if radius < wide else radius, float(src.radius_mm))
    return dataclasses.replace(src, center_mm=centre, radius_mm=radius,
                               power_w=float(src.power_w) * (radius / float(src.radius_mm)) ** 2)


# ---------------------------------------------------------------- one step: the next hit and its interface


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


@dataclass(eq=False)
class Bundle:
    """Rays in flight: origin, direction, weight (W), Stokes vector (S0 = 1) and its frame e1, last part."""

    o: np.ndarray
    d: np.ndarray
    w: np.ndarray
    S: np.ndarray
    e1: np.ndarray
    last: np.ndarray

    def take(self, sel) -> "Bundle":
        return Bundle(self.o[sel], self.d[sel], self.w[sel], self.S[sel], self.e1[sel], self.last[sel])


def emit(opt: GhostOptics, n: int, rng) -> Bundle:
    """``n`` rays of the source, each carrying power_w / n, unpolarized."""
    return emit_uniforms(opt, rng.random((n, 4)))


def emit_uniforms(opt: GhostOptics, u: np.ndarray, factor: np.ndarray | None = None) -> Bundle:
    """The source's rays for the uniforms ``u`` (n, 4), each carrying power_w / n (times ``factor``, the
    ray's 1 / p(u) when its uniforms were drawn with density p), unpolarized."""
    src = opt.source
    n = len(u)
    o, d = src.emit(u)
    S = np.zeros((n, 4))
    S[:, 0] = 1.0
    e1 = s_vector(d, np.tile([0.0, 0.0, 1.0], (n, 1)))
    w = np.full(n, float(src.power_w) / n)
    if factor is not None:
        w = w * factor
    return Bundle(np.ascontiguousarray(o), np.ascontiguousarray(d), w, S, e1, np.full(n, -1, np.int64))


def next_hits(opt: GhostOptics, b: Bundle):
    """First hits of the bundle: (part (-1: miss), distance from the origin, exact point, facing normal, front).

    As in the walk (``optical_surface``): a mesh hit is refined onto the part's exact surface; one that
    refines outside the clear aperture, or back onto the ray's own origin on its last part, is passed
    through and the ray cast again from just beyond it. (While every ray is cast, and where every ray of a
    cast hits one part and is accepted there, the rays are taken whole, not through index arrays: the same
    numbers, without a forced sequence's per-step copies of every ray.)"""
    n = len(b.w)
    part = np.full(n, -1, np.int64)
    point = np.zeros((n, 3))
    facing = np.zeros((n, 3))
    front = np.zeros(n, bool)
    todo: Any = _ALL  # the rays still to cast: every one (_ALL), then the index array of those passed through
    o = b.o  # copied before a ray passed through moves its origin
    last = b.last
    copied = False
    for _ in range(4):
        if isinstance(todo, np.ndarray) and len(todo) == 0:
            break
        o_todo, d_todo = o[todo], b.d[todo]
        tri, t = opt.isect.intersect(o_todo, d_todo)
        tri = np.asarray(tri, np.int64)
        t = np.asarray(t, float)
        hit_part = np.where(tri >= 0, opt.tri_part[np.maximum(tri, 0)], -1)
        retry = []
        lo = int(hit_part.min()) if len(hit_part) else -1
        one = lo >= 0 and lo == int(hit_part.max())  # every ray cast hits part lo
        for p in ((lo,) if one else np.unique(hit_part[hit_part >= 0])):
            g: Any
            rows: Any  # _ALL or an index array, as todo
            if one:
                g, rows, o_g, d_g, t_g = _ALL, todo, o_todo, d_todo, t
            else:
                g = np.flatnonzero(hit_part == p)
                rows = g if todo is _ALL else todo[g]
                o_g, d_g, t_g = o_todo[g], d_todo[g], t[g]
            surf = opt.surfaces[p]
            if surf is not None:
                tr, n_front, ok = surf.refine_hits(o_g, d_g, t_g)
                accept = ok & ~((last[rows] == p) & (tr < SELF_HIT_MM))
            else:
                tr, n_front, accept = t_g, opt.tri_normals[tri[g]], np.ones(len(t_g), bool)
            whole = bool(accept.all())
            if whole:
                r, o_r, d_r, t_r, n_r = rows, o_g, d_g, tr, n_front
            else:
                r = np.flatnonzero(accept) if rows is _ALL else rows[accept]
                o_r, d_r, t_r, n_r = o_g[accept], d_g[accept], tr[accept], n_front[accept]
            part[r] = p
            point[r] = o_r + t_r[:, None] * d_r
            fr = _dot(d_r, n_r) < 0
            front[r] = fr
            facing[r] = np.where(fr[:, None], n_r, -n_r)
            if whole:
                continue
            pass_ = ~accept
            again = np.flatnonzero(pass_) if rows is _ALL else rows[pass_]
            if not copied:
                o, last, copied = o.copy(), last.copy(), True
            # past the facet by the scene's offset: a ray leaving a flat surface meets its facet again at t = 0
            # in the intersector's float32 until it has moved a few ulps of the coordinates
            o[again] = o_g[pass_] + (t_g[pass_] + opt.eps_mm)[:, None] * d_g[pass_]
            last[again] = p
            retry.append(again)
        todo = np.concatenate(retry) if retry else np.zeros(0, np.int64)
    dist = _dot(point - b.o, b.d)
    return part, dist, point, facing, front


_ALL = slice(None)  # next_hits: every ray (a view, not a copy)


def fresnel(opt: GhostOptics, part, front, cos_i, dist):
    """(r_s, r_p, t_s, t_p, cos_t, eta, bulk) per hit (``Material.smooth_coefficients``)."""
    from straylight.engine.surface_geometry import smooth_coefficients_into

    m = len(part)
    out = (np.zeros(m, complex), np.zeros(m, complex), np.zeros(m, complex), np.zeros(m, complex),
           np.zeros(m), np.ones(m), np.ones(m))
    back = ~front
    for p in np.unique(part):
        g = np.flatnonzero(part == p)
        f_model, b_model = opt.models[p]
        for side, model in ((False, f_model), (True, b_model if b_model is not None else f_model)):
            gg = g[back[g] == side]
            if len(gg) and model is not None:
                smooth_coefficients_into(model, gg, back, cos_i, dist, out)
    return out


def interact(b: Bundle, point, facing, coeffs, reflect_it, eps_mm: float = EPS_MM) -> Bundle:
    """The bundle after its interface hits: reflected where ``reflect_it`` (per ray, or one bool for every ray:
    a forced sequence's step), else transmitted; weights times the branch's power for the ray's Stokes vector
    (the engine's Mueller matrices) and the bulk factor."""
    rs, rp, ts, tp, cos_t, eta, bulk = coeffs
    s = s_vector(b.d, facing)
    S = rotate_stokes(b.S, b.e1, s, b.d)
    if isinstance(reflect_it, (bool, np.bool_)):  # one branch for all: only its direction computed
        a_s, a_p = (rs, rp) if reflect_it else (ts, tp)
        d_new = reflect(b.d, facing) if reflect_it else refract(b.d, facing, eta, cos_t)
        offset = (eps_mm if reflect_it else -eps_mm) * facing
    else:
        a_s = np.where(reflect_it, rs, ts)
        a_p = np.where(reflect_it, rp, tp)
        d_new = np.where(reflect_it[:, None], reflect(b.d, facing), refract(b.d, facing, eta, cos_t))
        offset = (np.where(reflect_it, 1.0, -1.0) * eps_mm)[:, None] * facing
    So = apply_interface_mueller(a_s, a_p, S)
    w = b.w * So[:, 0] * bulk
    safe = np.where(So[:, :1] > 0, So[:, :1], 1.0)
    return Bundle(np.ascontiguousarray(point + offset), np.ascontiguousarray(d_new), w, So / safe, s, b.last)


# ---------------------------------------------------------------- the nominal sequence and the ghosts


def nominal_sequence(opt: GhostOptics, n_rays: int = 4000, seed: int = 0) -> tuple:
    """The design path: ((part, "T" | "R"), ...) up to the detector, the likelier branch at every interface.

    Of the sequences that reach the detector through at least one interface and carry at least
    :data:`NOMINAL_MIN_SHARE` of the strongest one's power, the one through the most interfaces: light that
    passes the front elements and then goes *around* the smaller ones (a lens file has no barrel) can carry
    more power than the design path, but it always skips some of the surfaces the design path crosses."""
    _has_dielectric(opt.models)
    rng = np.random.default_rng(seed)
    b = emit(opt, n_rays, rng)
    seqs: list[list[tuple[int, str]]] = [[] for _ in range(n_rays)]
    ids = np.arange(n_rays)
    power: dict = {}
    arrivals = 0  # rays that reach the detector through an interface
    for _ in range(MAX_NOMINAL_STEPS):
        if len(ids) == 0:
            break
        part, dist, point, facing, front = next_hits(opt, b)
        at_det = (part == opt.detector) & front
        for i, w in zip(ids[at_det], b.w[at_det]):
            key = tuple(seqs[i])
            power[key] = power.get(key, 0.0) + float(w)
            arrivals += any(a == "T" for _, a in key)
        go = np.flatnonzero((part >= 0) & ~at_det & np.array([p >= 0 and opt.is_interface(p) for p in part], bool))
        if len(go) == 0:
            break
        b, ids = b.take(go), ids[go]
        part, dist, point, facing, front = part[go], dist[go], point[go], facing[go], front[go]
        cos_i = np.clip(-_dot(b.d, facing), 0.0, 1.0)
        co = fresnel(opt, part, front, cos_i, dist)
        R = 0.5 * (np.abs(co[0]) ** 2 + np.abs(co[1]) ** 2)
        T = 0.5 * (np.abs(co[2]) ** 2 + np.abs(co[3]) ** 2)
        refl = R > T
        for i, p, r in zip(ids, part, refl):
            seqs[i].append((int(p), "R" if r else "T"))
        b.last = part
        b = interact(b, point, facing, co, refl, opt.eps_mm)
    through = {k: w for k, w in power.items() if any(a == "T" for _, a in k)}
    if arrivals < NOMINAL_MIN_ARRIVALS and n_rays < NOMINAL_MAX_RAYS and not (not through and any(k for k in power)):
        # a pupil far smaller than the source (a fisheye: 1 mm of entrance pupil in a 100 mm front element, 1e-4 of
        # the source's rays) leaves the design path unseen in a few thousand rays: look again with more
        return nominal_sequence(opt, n_rays * 8, seed)
    if not through and any(k for k in power):  # every path there reflects at each interface it meets
        raise GhostError(f"the light reaches the detector {opt.names[opt.detector]!r} by reflections alone (a mirror "
                         "system): no transmitting interface, so no ghost (ghosts come from lenses and windows)")
    if not through:
        hint = ""
        if opt.field_deg:  # the detector optics import sizes holds the image over the file's fields only
            radius = getattr(opt.surfaces[opt.detector], "outer_radius_mm", None)
            hint = (f"; at --field-deg {opt.field_deg:g} the image may miss the detector"
                    + (f" (radius {radius:.4g} mm)" if radius else "")
                    + f": import the lens at that field (optics import --field-deg {opt.field_deg:g}) and run "
                    "ghosts without --field-deg")
        raise GhostError(f"no source ray reaches the detector {opt.names[opt.detector]!r} through an interface "
                         "(a lens or window) along a specular path" + hint)
    strongest = max(through.values())
    kept = {k: w for k, w in through.items() if w >= NOMINAL_MIN_SHARE * strongest}
    return max(kept, key=lambda k: (len(k), kept[k]))  # light around the lenses (no barrel) is not the design path


def reflection_sites(nominal) -> list:
    """Positions in the nominal sequence where the design transmits through an interface."""
    return [i for i, (_, act) in enumerate(nominal) if act == "T"]


def ghost_reflections(nominal, order: int = 2) -> list:
    """Every tuple of reflection positions r1 > r2 < r3 > r4 ... (even length <= order) among the sites."""
    sites = reflection_sites(nominal)
    out = []

    def grow(prefix):
        if prefix and len(prefix) % 2 == 0:
            out.append(tuple(prefix))
        if len(prefix) >= order:
            return
        last = prefix[-1] if prefix else -1
        forward = len(prefix) % 2 == 0  # the next reflection happens going forward (after a backward one)
        for s in sites:
            if (forward and s > last) or (not forward and s < last):
                grow(prefix + [s])

    grow([])
    return out


def ghost_sequence(nominal, refl) -> tuple:
    """The forced sequence ((part, action), ...) of the ghost with reflections at nominal positions ``refl``."""
    seq = []
    cur = 0
    for k, r in enumerate(refl):
        if k % 2 == 0:  # going forward from cur up to r
            seq += list(nominal[cur:r])
            cur = r - 1
        else:  # going backward from cur down to r
            seq += [nominal[j] for j in range(cur, r, -1)]
            cur = r + 1
        seq.append((nominal[r][0], "R"))
    seq += list(nominal[cur:])
    return tuple(seq)


def normal_incidence_powers(opt: GhostOptics, p: int) -> tuple:
    """(R, T) of part ``p`` at normal incidence, unpolarized, each the mean over its two sides (its own coating
    and film stack; ``Material.smooth_coefficients``); (0, 1) for a part with no specular interface."""
    f_model, b_model = opt.models[p]
    powers = []
    for back, model in ((False, f_model), (True, b_model if b_model is not None else f_model)):
        c = None if model is None else model.smooth_coefficients(np.ones(1), back=back)
        if c is not None:
            powers.append((float(c.reflectance("u")[0]), float(c.transmittance("u")[0])))
    if not powers:
        return 0.0, 1.0
    return sum(r for r, _ in powers) / len(powers), sum(t for _, t in powers) / len(powers)


def ghost_priors(opt: GhostOptics, nominal, refls) -> list:
    """A cheap guess of each ghost's share of the source, to trace the likely-brightest first under a time cap:
    the product along its sequence of the normal-incidence reflectance where it reflects and transmittance where
    it transmits (:func:`normal_incidence_powers`; no vignetting, angles or absorption in the glass)."""
    powers = {p: normal_incidence_powers(opt, p) for p, _ in nominal}
    out = []
    for refl in refls:
        prior = 1.0
        for p, act in ghost_sequence(nominal, refl):
            prior *= powers[p][0] if act == "R" else powers[p][1]
        out.append(prior)
    return out


# ---------------------------------------------------------------- tracing one sequence


@dataclass(eq=False)
class Arrivals:
    """Per traced ray: its power at the detector (0 when blocked); the arrivals' points and directions."""

    per_ray_w: np.ndarray
    points: np.ndarray
    dirs: np.ndarray
    weights: np.ndarray
    uniforms: np.ndarray | None = None  # (n, 2): each ray's first two source uniforms, as traced


def trace_sequence(opt: GhostOptics, seq, n: int, rng, table=None) -> Arrivals:
    """``n`` source rays forced through ``seq`` and into the detector; with ``table`` (an
    :class:`straylight.engine.entrance_sampling.EntranceTable` over the source's first two uniforms) the
    rays are drawn from its density p and carry 1 / p (the same expectation, by importance sampling)."""
    u = rng.random((n, 4))
    factor = None
    if table is not None:
        from straylight.engine.entrance_sampling import warp

        factor = warp(table, u)
    b = emit_uniforms(opt, u, factor)
    drawn = u[:, :2].copy()
    ids = np.arange(n)
    for p, act in seq:
        if len(ids) == 0:
            break
        part, dist, point, facing, front = next_hits(opt, b)
        on = part == p
        if not on.all():  # (where every ray goes on, no copy)
            ok = np.flatnonzero(on)
            b, ids = b.take(ok), ids[ok]
            part, dist, point, facing, front = part[ok], dist[ok], point[ok], facing[ok], front[ok]
        cos_i = np.clip(-_dot(b.d, facing), 0.0, 1.0)
        co = fresnel(opt, part, front, cos_i, dist)
        b.last = part
        b = interact(b, point, facing, co, act == "R", opt.eps_mm)
        alive = b.w > 0
        if not alive.all():
            live = np.flatnonzero(alive)
            b, ids = b.take(live), ids[live]
    per_ray = np.zeros(n)
    if len(ids) == 0:
        return Arrivals(per_ray, np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), drawn)
    part, dist, point, facing, front = next_hits(opt, b)
    at = np.flatnonzero((part == opt.detector) & front)
    per_ray[ids[at]] = b.w[at]
    return Arrivals(per_ray, point[at], b.d[at], b.w[at], drawn)


def sample_polylines(opt: GhostOptics, seq, n_paths: int = 6, rays: int = 256, seed: int = 0) -> list:
    """Up to ``n_paths`` rays of ``seq`` that reach the detector, each as its (k, 3) points in mm (source,
    every hit, the detector): the rays the 3-D view draws for a ghost."""
    rng = np.random.default_rng(seed)
    b = emit(opt, rays, rng)
    ids = np.arange(rays)
    trail = [b.o.copy()]
    alive_at = [ids.copy()]
    for p, act in list(seq) + [(opt.detector, "D")]:
        if len(ids) == 0:
            return []
        part, dist, point, facing, front = next_hits(opt, b)
        ok = np.flatnonzero((part == p) & (front if act == "D" else True))
        b, ids = b.take(ok), ids[ok]
        point, facing, front, part, dist = point[ok], facing[ok], front[ok], part[ok], dist[ok]
        trail.append(point.copy())
        alive_at.append(ids.copy())
        if act == "D":
            break
        cos_i = np.clip(-_dot(b.d, facing), 0.0, 1.0)
        co = fresnel(opt, part, front, cos_i, dist)
        b.last = part
        b = interact(b, point, facing, co, np.full(len(ids), act == "R"), opt.eps_mm)
    out = []
    for i in ids[:n_paths]:
        out.append(np.array([pts[np.flatnonzero(at == i)[0]] for pts, at in zip(trail, alive_at)]))
    return out


def write_view3d(table: "GhostTable", opt: GhostOptics, setup, path, top: int = 12, seed: int = 0):
    """DIR/view3d.html: the instrument with the nominal path and the ``top`` strongest ghosts drawn, each its own
    selectable path (straylight.view3d)."""
    from straylight.view3d import PathSample, view_data, view_page

    import atomicio

    samples = []
    p_nom = table.nominal.power_w or 0.0
    nominal_seq = table.nominal_parts
    samples.append(PathSample(0, "nominal image", 1.0, 0.0,
                              [p.tolist() for p in sample_polylines(opt, nominal_seq, seed=seed)]))
    for rank, r in enumerate(table.rows[:top], start=1):
        if r.power_w is None or r.stderr_w is None or r.fraction_of_nominal is None:
            break  # the untraced, listed last (the time cap)
        poly = sample_polylines(opt, r.parts, seed=seed + rank)
        if poly:
            samples.append(PathSample(rank, "ghost " + " > ".join(r.surfaces), r.fraction_of_nominal,
                                      r.stderr_w / p_nom if p_nom > 0 else 0.0,
                                      [p.tolist() for p in poly]))
    page = view_page(view_data(setup, {}, {}, samples, f"Ghosts at {table.detector} (field {table.field_deg:g} deg)"))
    return atomicio.write_text(path, page)


# ---------------------------------------------------------------- the table


@dataclass
class GhostRow:
    """One ghost (or the nominal image): CONTRACTS 8.4's columns."""

    surfaces: list
    reflections: list
    power_w: float | None  # None (with stderr_w and fraction_of_nominal): never traced, the time cap came first
    stderr_w: float | None
    fraction_of_nominal: float | None
    focus_mm: float | None
    radius_mm: float | None
    peak_ratio: float | None
    rays: int
    sequence: list = field(default_factory=list)
    parts: tuple = field(default=(), repr=False)  # the forced sequence ((part index, action), ...)
    map_key: str = field(default="", repr=False)  # its map in GhostTable.maps (the label, made unique)
    # where none of its rays reached the detector: its power is below this at 95 % (3 x the source's power /
    # rays: each ray carries at most the source's power / rays, and 0 arrivals in n rays puts the arrival
    # probability below 3 / n at 95 %); None where rays arrived
    upper_w: float | None = None


class _Accumulator:
    """Running sums over batches: per-ray mean and variance, arrivals for the focus and the map."""

    def __init__(self, frame):
        self.frame = frame
        self.n = 0
        self.s1 = 0.0
        self.s2 = 0.0
        self.map = np.zeros((MAP_BINS, MAP_BINS))
        self.halves = np.zeros((2, MAP_BINS, MAP_BINS))  # the map of the even batches and of the odd ones
        self.batches = np.zeros(2, dtype=np.int64)  # how many batches each half holds
        self.squares = np.zeros((MAP_BINS, MAP_BINS))  # per cell, the sum of the squared weights
        self.m = np.zeros(12)  # weighted moments for centroid, RMS and focus

    def add(self, arr: Arrivals):
        n_new = len(arr.per_ray_w)
        self.n += n_new
        self.s1 += float(arr.per_ray_w.sum())
        self.s2 += float((arr.per_ray_w ** 2).sum())
        half_k = int(self.batches.sum() % 2)
        self.batches[half_k] += 1
        if len(arr.weights) == 0:
            return
        origin, u, v, a, half = self.frame
        rel = arr.points - origin
        q = np.column_stack([rel @ u, rel @ v])
        along = arr.dirs @ a
        slope = np.column_stack([arr.dirs @ u, arr.dirs @ v]) / np.where(np.abs(along) > 1e-12, along, 1e-12)[:, None]
        w = arr.weights
        cells = [[-half, half], [-half, half]]
        binned = np.histogram2d(q[:, 0], q[:, 1], bins=MAP_BINS, range=cells, weights=w)[0]
        self.map += binned
        self.halves[half_k] += binned
        self.squares += np.histogram2d(q[:, 0], q[:, 1], bins=MAP_BINS, range=cells, weights=w * w)[0]
        self.m += np.array([w.sum(), (w * q[:, 0]).sum(), (w * q[:, 1]).sum(), (w * (q ** 2).sum(1)).sum(),
                            (w * slope[:, 0]).sum(), (w * slope[:, 1]).sum(), (w * (slope ** 2).sum(1)).sum(),
                            (w * (q * slope).sum(1)).sum(), 0, 0, 0, 0])

    def geometry(self):
        """(focus_mm or None, RMS radius mm or None)."""
        W = self.m[0]
        if W <= 0:
            return None, None
        cq = self.m[1:3] / W
        rms2 = self.m[3] / W - float(cq @ cq)
        cs = self.m[4:6] / W
        var_u = self.m[6] / W - float(cs @ cs)
        cov = self.m[7] / W - float(cq @ cs)
        focus = None if var_u <= 1e-18 else -cov / var_u
        return focus, math.sqrt(max(rms2, 0.0))


def peak_estimate(acc: "_Accumulator") -> float:
    """The peak of ``acc``'s map (its units: the summed weights per cell), as the mean over a block of cells.

    The largest of many block means is biased up by their noise, so each half of the batches chooses a block
    (its largest mean) and the other half's mean there is read: the two readings, each scaled to all the
    batches, are averaged (an unbiased reading of blocks chosen without it). The block is the smallest of
    :data:`PEAK_BLOCKS` whose chosen block's sum is known to :data:`PEAK_REL_ERROR` (from the summed
    squared weights); the largest when none is. A map of one half only (a single batch) gives the plain
    largest :data:`PEAK_CELLS` block mean."""
    from scipy.ndimage import uniform_filter

    n_a, n_b = (int(k) for k in acc.batches)
    if n_a == 0 or n_b == 0 or not (acc.halves[0].any() and acc.halves[1].any()):
        return float(uniform_filter(acc.map, size=PEAK_CELLS, mode="constant").max())
    total = n_a + n_b
    peak = 0.0
    for size in PEAK_BLOCKS:
        a, b, sq = (uniform_filter(x, size=size, mode="constant") for x in (acc.halves[0], acc.halves[1], acc.squares))
        at_a, at_b = np.unravel_index(np.argmax(a), a.shape), np.unravel_index(np.argmax(b), b.shape)
        peak = 0.5 * (b[at_a] * total / n_b + a[at_b] * total / n_a)
        whole = a + b
        worst = max(math.sqrt(sq[at]) / (whole[at] * size) if whole[at] > 0 else math.inf for at in (at_a, at_b))
        if worst <= PEAK_REL_ERROR:
            break
    return float(max(peak, 0.0))


def detector_frame(opt: GhostOptics):
    """(origin, u, v, a (the direction light travels into the detector), half-width mm) of the detector."""
    surf = opt.surfaces[opt.detector]
    if surf is not None and hasattr(surf, "outer_radius_mm"):
        a = -np.asarray(surf.axis, float)
        u, v = surf.rotation[0], surf.rotation[1]
        return np.asarray(surf.vertex_mm, float), u, v, a, float(surf.outer_radius_mm)
    mask = opt.tri_part == opt.detector
    raise GhostError(f"the detector {opt.names[opt.detector]!r} needs an exact plane surface "
                     f"(CONTRACTS 6.4; {int(mask.sum())} triangles of mesh given)")


def _row_dict(r: GhostRow) -> dict:
    return {k: v for k, v in r.__dict__.items() if k not in ("parts", "map_key")}


@dataclass(eq=False)
class GhostTable:
    """The ghost table: the nominal image and every ghost, sorted by power (CONTRACTS 8.4)."""

    detector: str
    order: int
    field_deg: float
    nominal: GhostRow
    rows: list
    maps: dict
    half_width_mm: float
    seconds: float = 0.0
    notes: list = field(default_factory=list)
    nominal_parts: tuple = ()
    optics: "GhostOptics | None" = None  # the GhostOptics it was traced on (the 3-D view draws its rays)
    # the notes a user acts on (ghosts stopped short of the target or not measured), each also in ``notes``: the
    # command prints these as warnings, the rest only in ghosts.md; ghosts.json keeps every note in "notes"
    warnings: list = field(default_factory=list)

    def to_json_dict(self) -> dict:
        return {"detector": self.detector, "order": self.order, "field_deg": self.field_deg,
                "map_bins": MAP_BINS, "nominal": _row_dict(self.nominal),
                "ghosts": [_row_dict(r) for r in self.rows], "seconds": self.seconds, "notes": list(self.notes)}


def _notes(runs, rows, timed_out: bool, *, target_rel_error, max_rays, max_total_rays, max_seconds,
           guide_below) -> tuple:
    """The table's notes and, among them, its warnings (what stopped ghosts short of ``target_rel_error`` or left
    them unmeasured: a user acts on those); the rest says how the table was traced."""
    n = len(runs)
    notes, warnings = [], []

    def warn(text):
        notes.append(text)
        warnings.append(text)

    short = [r for r in runs if not r.done and r.traced]
    untraced = sum(not r.traced for r in runs)
    if timed_out:
        rel = sorted(r.err / r.mean for r in short if r.mean > 0)
        reached = f", at up to {rel[-1]:.1%} relative error (median {rel[len(rel) // 2]:.1%})" if rel else ""
        if short:
            warn(f"{len(short)} of {n} ghosts were stopped by the time cap (--max-seconds {max_seconds:g}) before "
                 f"{target_rel_error:g} relative error{reached}; their errors are as listed")
        if untraced:
            warn(f"{untraced} of {n} ghosts were not traced before the time cap (--max-seconds {max_seconds:g}): "
                 "they have no estimate (power and error empty, null in ghosts.json) and are listed last")
    elif short:
        warn(f"{len(short)} of {n} ghosts reached the table's ray budget ({max_total_rays} rays, "
             f"--max-total-rays) before {target_rel_error:g} relative error; their errors are as listed")
    bounds = [r.upper_w for r in rows if r.upper_w is not None]
    if bounds:
        warn(f"{len(bounds)} of {n} ghosts had no ray reach the detector (listed as 0 +- 0): each is "
             f"below 3 x the source's power / its rays at 95 % (upper_w; at most {max(bounds):.1e} W)")
    guided = sum(r.table is not None and r.acc.n > 0 for r in runs)  # a table learnt as the budget ran out: unused
    if guided:
        notes.append(f"{guided} of {n} ghosts get through from only a small part of the incoming beam (fewer than "
                     f"{guide_below:.0%} of their first, evenly spread rays reached the detector), so the rest of their "
                     "rays were aimed at that part, weighted to keep their power unbiased; their ray counts include "
                     "the first rays")
    capped = sum(r.capped for r in runs)
    if capped:
        warn(f"{capped} of {n} ghosts reached --max-rays ({max_rays} rays each) before "
             f"{target_rel_error:g} relative error; their errors are as listed")
    return notes, warnings


def default_workers() -> int:
    """The cores this process may run on (its CPU affinity where the platform tells it, else ``os.cpu_count``)."""
    import os

    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def _can_fork() -> bool:
    """Can this process fork workers? Not where the platform has no fork, nor in a daemonic process (a pool's own
    worker: it may have no children)."""
    import multiprocessing

    return "fork" in multiprocessing.get_all_start_methods() and not multiprocessing.current_process().daemon


_WORKER: dict = {}  # in a forked worker of ghost_table's pool: the table's Run class (_Pool)


def _worker_start(run_class) -> None:
    _WORKER["Run"] = run_class


def _advance_in_worker(state: dict, limit) -> dict:
    """A forked worker's task: the run whose state (its ``__dict__``: random stream, sums, batches) is ``state``,
    advanced to ``limit``; its new state back."""
    run = object.__new__(_WORKER["Run"])
    run.__dict__.update(state)
    run.advance(limit)
    return run.__dict__


class _Pool:
    """``workers`` processes forked from this one (each inherits the optics, the intersector's built BVH and the
    compiled kernels as they are: nothing rebuilt, nothing pickled but the runs' states), tracing the runs of a
    round (ghost_table's ``reach``) at most one a worker at a time. A run's state goes to a worker and comes back
    whole, so a run continues its own random stream wherever it is traced: the table is the serial one."""

    def __init__(self, workers: int, run_class, dispatch, limit_of):
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        self.workers, self.dispatch, self.limit_of = workers, dispatch, limit_of
        # forked at the first task, from this thread (the class goes to the workers in the fork, not pickled)
        self.executor = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork"),
                                            initializer=_worker_start, initargs=(run_class,))

    def round(self, todo, first_round: bool, tick) -> None:
        """Trace the round ``todo`` ((k, run, limit), ...): each run dispatched in order as a worker frees (none
        once ``dispatch`` says the deadline is past); returns when every dispatched run is back."""
        from concurrent.futures import FIRST_COMPLETED, wait

        pending: dict = {}
        queue = iter(todo)
        open_ = True
        while True:
            while open_ and len(pending) < self.workers:
                item = next(queue, None)
                if item is None or not self.dispatch(item[1]):
                    open_ = False
                    break
                k, run, lim = item
                future = self.executor.submit(_advance_in_worker, run.__dict__, self.limit_of(run, lim))
                pending[future] = (k, run)
            if not pending:
                return
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                k, run = pending.pop(future)
                run.__dict__.update(future.result())
                if tick is not None and first_round:
                    tick(k)

    def close(self) -> None:
        self.executor.shutdown(wait=True, cancel_futures=True)


def ghost_table(opt: GhostOptics, order: int = 2, target_rel_error: float = 0.02, min_fraction: float = 1e-6,
                batch_rays: int | None = None, max_rays: int = 400_000, seed: int = 0, on_ghost=None,
                max_total_rays: int = MAX_TOTAL_RAYS, guide_below: float = GUIDE_BELOW,
                max_seconds: float | None = None, execution=None, started: float | None = None,
                reserve_s: float = 0.0) -> GhostTable:
    """Every ghost up to ``order`` reflections: power +- error, focus, radius, peak irradiance ratio.

    The ghosts share ``max_total_rays`` (the nominal image's rays aside) by water-filling: each round gives
    every unfinished ghost an equal share of what is left, and a ghost continues its own random stream where
    it stopped, so a table whose ghosts need fewer rays in all is the one traced without the budget, ray for
    ray. Ghosts the budget stops above ``target_rel_error`` keep the error they reached (``notes`` and
    ``warnings`` say how many): a 16-surface lens's 120 ghosts would otherwise take minutes. ``batch_rays``
    None: 4096, or for the ghosts fewer (not below 256) where two batches for every ghost would exceed the
    budget (order 4: thousands of ghosts; the nominal image keeps 4096).

    ``max_seconds``: a wall-clock cap (``monotonic``) counted from ``started`` (a ``monotonic()`` reading:
    :func:`ghosts`, which the command line calls, passes its call's, so the cap bounds the whole call, the nominal
    image's trace included), or, ``started`` None, from the end of the nominal image's trace (the cap the ghosts
    share); the ghosts stop ``reserve_s`` before it (the command line's time to write its files). Under it the
    same schedule is traced one batch a ghost per round, every ghost's first batch before any
    ghost's second (the first batches going out by :func:`ghost_priors`, the likely-brightest first; later
    rounds by the estimates so far, the largest first), so the cap stops the ghosts as the budget does (each
    keeps the estimate it reached) and leaves each with one: the batches of the ghosts still without one
    shrink (not below 256) where the time measured so far says that one each would take more than
    :data:`FIRST_ROUND_SHARE` of the cap. A ghost the
    cap left untraced has no estimate: power, error and fraction None (null in ghosts.json, empty in
    ghosts.csv), listed last.

    ``execution``: a :class:`straylight.execution.Execution` whose ``workers`` is the number of processes the
    ghosts are traced on (None, or its ``workers`` None: this process alone, as a platform that cannot fork;
    the command line and :func:`ghosts` pass :func:`default_workers`). Each round's ghosts go to the workers in order, one at a time a worker, and a
    ghost's state comes back whole, so without the cap the table is the same for any ``workers``, number for
    number. Under the cap each ghost still gets one batch before any its second (a round ends when its last
    ghost is back), the deadline is checked as each ghost's batch is handed out, and the batch fit measures the
    wall time: K workers trace up to K times the rays by the deadline, so which ghosts a cap stops, and where,
    depends on K as it depends on the machine."""
    import time

    if order < 2 or order % 2:
        raise GhostError(f"--order must be an even number >= 2, got {order}")
    workers = getattr(execution, "workers", None) or 1
    if max_seconds is not None and not max_seconds > 0:
        raise GhostError(f"--max-seconds must be > 0, got {max_seconds:g}")
    t0 = time.perf_counter()
    nominal = nominal_sequence(opt, seed=seed)
    frame = detector_frame(opt)
    half = frame[4]
    cell_mm2 = (2 * half / MAP_BINS) ** 2
    refls = ghost_reflections(nominal, order)
    if not refls:
        raise GhostError("the nominal path crosses no transmitting interface: no ghost to list")
    nominal_batch = int(batch_rays or BATCH_RAYS)
    auto_batch = batch_rays is None
    if batch_rays is None:  # two batches a ghost within the budget (an order-4 table has thousands of ghosts)
        batch_rays = int(np.clip(max_total_rays // (2 * len(refls)), MIN_BATCH_RAYS, BATCH_RAYS))

    class Run:
        """One sequence's estimate, traced in batches up to a ray limit at a time (its own random stream).

        Its first :data:`LEARN_BATCHES` batches are uniform over the source (more, up to
        :data:`LEARN_MAX_BATCHES`, until :data:`GUIDE_MIN_HITS` of their rays arrive). When few of their rays arrive
        (under ``guide_below``) and the target is further than :data:`GUIDE_AFTER` times their rays away, they
        only learn where the sequence's rays start (an entrance table of their per-ray powers, as the pilot of
        straylight.engine.entrance_sampling learns one) and the estimate starts again from rays drawn from it,
        each carrying 1 / p: unbiased (the table is fixed before those rays), and a lens whose stop passes a
        few per cent of the source's disk traces those few per cent."""

        def __init__(self, seq, k, floor_w=None, batch=None):
            self.seq, self.floor_w, self.batch = seq, floor_w, int(batch or batch_rays)
            self.k, self.prior = k, 1.0  # its place in the table's list; its guessed power (ghost_priors)
            self.rng = np.random.default_rng([seed, k])
            self.acc = _Accumulator(frame)
            self.done = False
            self.capped = False  # stopped by max_rays above the target error
            self.mean = self.err = 0.0
            self.traced = 0  # rays traced, the learning batches' too (the budget's count)
            self.table = None
            self.uniform_acc = self.acc
            self.learning: list | None = []  # the uniform batches' (uniforms, per-ray power) while they may teach

        def advance(self, limit: float = math.inf):
            batch_rays = self.batch  # this run's batch (the nominal image's may differ from the ghosts')
            while not self.done and self.traced < limit:
                arr = trace_sequence(opt, self.seq, batch_rays, self.rng, self.table)
                self.traced += batch_rays
                self.acc.add(arr)
                if self.learning is not None:
                    self.learning.append((arr.uniforms, arr.per_ray_w))
                acc = self.acc
                # each ray carries power_w / batch_rays: the power is batch_rays times the per-ray mean
                mean = self.mean = acc.s1 / acc.n * batch_rays
                err = self.err = math.sqrt(max(acc.s2 / acc.n - (acc.s1 / acc.n) ** 2, 0.0) / max(acc.n - 1, 1)) \
                    * batch_rays
                reached = mean > 0 and err <= target_rel_error * mean and acc.n >= 2 * batch_rays
                if self.traced >= max_rays or reached:
                    self.done = True
                    self.capped = not reached and not (self.floor_w is not None and mean + 4 * err < self.floor_w) \
                        and mean > 0
                elif self.learning is not None and len(self.learning) >= LEARN_BATCHES and self._guide(mean, err):
                    continue  # the estimate starts again from the table's rays
                elif self.floor_w is not None and acc.n >= 4 * batch_rays and mean + 4 * err < self.floor_w:
                    self.done = True  # below the fraction of the nominal power asked for, with confidence
                elif mean == 0 and acc.n >= 4 * batch_rays:
                    self.done = True
            return self

        def _guide(self, mean: float, err: float) -> bool:
            """After the learning batches: draw the rest from their table when that pays (class doc)."""
            from straylight.engine.entrance_sampling import table_from_contributions

            learning = self.learning
            assert learning is not None  # (called while the uniform batches teach)
            u = np.concatenate([a for a, _ in learning])
            x = np.concatenate([w for _, w in learning])
            hits = int(np.count_nonzero(x))
            if hits < GUIDE_MIN_HITS and len(learning) < LEARN_MAX_BATCHES:
                return False  # too few arrivals to learn from yet: the uniform rays go on, and on teaching
            self.learning = None
            far = mean <= 0 or (err / (target_rel_error * mean)) ** 2 > GUIDE_AFTER
            if not far or hits < GUIDE_MIN_HITS or hits >= guide_below * len(x):
                return False
            self.table = table_from_contributions(u, x)
            self.uniform_acc, self.acc = self.acc, _Accumulator(frame)
            return True

        def result(self):
            acc = self.acc if self.acc.n else self.uniform_acc  # stopped right after learning: the uniform rays' own
            focus, radius = acc.geometry()
            scale = (self.batch / acc.n) / cell_mm2  # summed weights per cell -> W/mm^2
            return self.mean, self.err, focus, radius, acc.map * scale, self.traced, peak_estimate(acc) * scale

    p_nom, e_nom, f_nom, r_nom, map_nom, n_nom, peak_nom = Run(nominal, 0, batch=nominal_batch).advance().result()
    if not p_nom > 0:  # every ghost's fraction and peak ratio would be undefined: nothing to rank them against
        raise GhostError(f"no light reaches the detector {opt.names[opt.detector]!r} along the nominal path "
                         f"({' > '.join(opt.names[q] for q, _ in nominal)}) in {n_nom} rays: the image surface may "
                         "sit in the incoming beam, or the path met by chance is not the lens's design path")
    nom_row = GhostRow([], [], p_nom, e_nom, 1.0, f_nom, r_nom, 1.0 if peak_nom > 0 else None, n_nom,
                       [opt.names[p] for p, _ in nominal])
    # every ghost's first share is at least two batches (its error needs two); where the ghosts are so many that
    # two batches each would pass the budget (a 37-surface zoom: 666 ghosts, 5.5e6 rays of 4096-ray batches),
    # their batches are smaller (batch_rays above) so that the first round fits it
    runs = [Run(ghost_sequence(nominal, refl), k, floor_w=min_fraction * p_nom) for k, refl in enumerate(refls, 1)]
    priors = ghost_priors(opt, nominal, refls)
    for run, prior in zip(runs, priors):
        run.prior = prior
    t_ghosts = monotonic()
    deadline = None if max_seconds is None else max(
        (t_ghosts if started is None else started) + max_seconds - reserve_s,
        t_ghosts + MIN_GHOST_SHARE * max_seconds)  # a slow nominal trace leaves the ghosts a part of the cap still
    timed_out = False
    fit = {"batch": batch_rays, "ray_parts": 0, "parts_left": sum(len(r.seq) for r in runs)}

    def fit_batch(run):
        """Under the cap, before a ghost's first batch: its size, so that the ghosts still without one take what is
        left of FIRST_ROUND_SHARE of the cap at the seconds per ray and part crossed measured so far (shrinking
        only, to MIN_BATCH_RAYS at least; a batch's fixed cost makes a smaller batch's rays dearer, which the next
        ghosts' time shows, and the batch shrinks again)."""
        now = monotonic()
        if fit["ray_parts"]:
            assert deadline is not None  # (fitted under the cap only)
            left = t_ghosts + FIRST_ROUND_SHARE * (deadline - t_ghosts) - now
            need = (now - t_ghosts) / fit["ray_parts"] * fit["batch"] * fit["parts_left"]
            if need > left:
                fit["batch"] = max(MIN_BATCH_RAYS, int(fit["batch"] * max(left, 0.0) / need))
        run.batch = fit["batch"]
        fit["ray_parts"] += run.batch * len(run.seq)
        fit["parts_left"] -= len(run.seq)

    def reach(limits, tick=None):
        """Trace each (k, run, limit) up to its limit, each run on its own stream (the same rays in any order).
        Under ``max_seconds``, one batch a run per round, every run's before any run's next, until the deadline;
        ``tick(k)`` after run k's first round. With a pool, the round's runs are traced by its workers, at most
        one run a worker at a time, dispatched in the round's order (the deadline and the batch fit checked at
        each dispatch, as here before each batch); the round ends when its last run is back."""
        nonlocal timed_out
        first_round = True
        while todo := [(k, run, lim) for k, run, lim in limits if not run.done and run.traced < lim]:
            todo.sort(key=lambda item: queue_key(item[1]))
            if pool is not None:
                pool.round(todo, first_round, tick)
                if timed_out:
                    return
            else:
                for k, run, lim in todo:
                    if not dispatch(run):
                        return
                    run.advance(limit_of(run, lim))
                    if tick is not None and first_round:
                        tick(k)
            first_round = False

    def queue_key(run):
        """The order a round's ghosts go out in (under the cap, the ones the deadline reaches last go without): a
        ghost with an estimate by it (largest first), before one without, by its prior (largest first; ghost_priors),
        then as listed. Each ghost on its own stream: without the cap the order changes no number."""
        return (0, -run.mean, -run.prior, run.k) if run.traced else (1, 0.0, -run.prior, run.k)

    def dispatch(run) -> bool:
        """Before a run's batch under the cap: False (and timed out) once the deadline is past; else its batch
        fitted, before its first."""
        nonlocal timed_out
        if deadline is not None:
            if monotonic() >= deadline:
                timed_out = True
                return False
            if not run.traced and auto_batch:
                fit_batch(run)
        return True

    def limit_of(run, lim):
        return lim if deadline is None else min(lim, run.traced + run.batch)

    n_workers = 1 if len(runs) < 2 or not _can_fork() else min(int(workers), len(runs))
    pool = _Pool(n_workers, Run, dispatch, limit_of) if n_workers > 1 else None
    first = max(2 * batch_rays, max_total_rays // len(runs))
    try:
        # on_ghost: a callable(k, n) told after each ghost's first share (a progress bar; under the cap, its first
        # batch)
        reach([(k, run, first) for k, run in enumerate(runs, start=1)],
              None if on_ghost is None else lambda k: on_ghost(k, len(runs)))
        while not timed_out:  # the rest of the budget, shared equally among the ghosts not yet at their target
            open_ = [r for r in runs if not r.done]
            share = (max_total_rays - sum(r.traced for r in runs)) // max(len(open_), 1)
            if not open_ or share < batch_rays:
                break
            reach([(0, run, run.traced + share) for run in open_])
    finally:
        if pool is not None:
            pool.close()
    rows = []
    maps = {"nominal": map_nom}
    for refl, run in zip(refls, runs):
        names = [opt.names[nominal[i][0]] for i in refl]
        label = " > ".join(names)
        if label in maps:  # a part the design path crosses twice (a Mangin mirror's glass): two ghosts, one label
            label += f" (positions {', '.join(str(i) for i in refl)})"
        sequence = [opt.names[q] for q, _ in run.seq]
        if not run.traced:  # the time cap came first: no estimate, not a measured 0
            maps[label] = np.zeros((MAP_BINS, MAP_BINS))
            rows.append(GhostRow(names, list(refl), None, None, None, None, None, None, 0, sequence, tuple(run.seq),
                                 label))
            continue
        p, e, f, r, m, n, peak = run.result()
        maps[label] = m
        rows.append(GhostRow(names, list(refl), p, e, p / p_nom if p_nom > 0 else float("nan"), f, r,
                             peak / peak_nom if peak_nom > 0 else None, n, sequence, tuple(run.seq),
                             label, upper_w=3.0 * float(opt.source.power_w) / n if p <= 0.0 and n > 0 else None))
    rows.sort(key=lambda r: (r.power_w is None, -(r.power_w or 0.0)))  # the untraced last
    notes, warnings = _notes(runs, rows, timed_out, target_rel_error=target_rel_error, max_rays=max_rays,
                             max_total_rays=max_total_rays, max_seconds=max_seconds, guide_below=guide_below)
    return GhostTable(opt.names[opt.detector], order, 0.0, nom_row, rows, maps, half, time.perf_counter() - t0,
                      notes=notes, nominal_parts=tuple(nominal), warnings=warnings)


# ---------------------------------------------------------------- files and the picture

CSV_COLUMNS = ("rank", "surfaces", "power_w", "stderr_w", "fraction_of_nominal", "focus_mm", "radius_mm",
               "peak_ratio", "rays", "sequence")


def _cell(v) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return ""
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)


def write_table(table: GhostTable, directory) -> list:
    """DIR/ghosts.csv, ghosts.json, ghosts.md and ghosts.png (the irradiance maps); returns the paths."""
    from pathlib import Path

    import atomicio

    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    lines = [",".join(CSV_COLUMNS)]
    for rank, r in enumerate(table.rows, start=1):
        vals = [rank, " > ".join(r.surfaces), r.power_w, r.stderr_w, r.fraction_of_nominal, r.focus_mm,
                r.radius_mm, r.peak_ratio, r.rays, " -> ".join(r.sequence)]
        lines.append(",".join(_cell(v) for v in vals))
    out = [atomicio.write_text(d / "ghosts.csv", "\n".join(lines) + "\n"),
           atomicio.write_json(d / "ghosts.json", table.to_json_dict()),
           atomicio.write_text(d / "ghosts.md", markdown(table))]
    out.append(plot_maps(table, d / "ghosts.png"))
    return out


def markdown(table: GhostTable, top: int = 50, warnings: bool = True) -> str:
    """ghosts.md: the nominal image, the notes (and the warnings, unless ``warnings`` is False: the command prints
    those on stderr), the ``top`` strongest ghosts."""
    n = table.nominal
    said = [f"Warning: {note}." if note in table.warnings else f"Note: {note}." for note in table.notes
            if warnings or note not in table.warnings]
    lines = [f"# Ghosts at {table.detector} (order {table.order}, field {table.field_deg:g} deg)", "",
             f"Nominal image: {n.power_w:.4e} W +- {n.stderr_w:.1e}, RMS radius "
             f"{_cell(n.radius_mm)} mm; {len(table.rows)} ghosts, {table.seconds:.1f} s.", "",
             *said, *([""] if said else []),
             "| rank | surfaces | power (W) | stderr (W) | of nominal | focus (mm) | radius (mm) | peak ratio |",
             "|---|---|---|---|---|---|---|---|"]
    for rank, r in enumerate(table.rows[:top], start=1):
        if r.power_w is None or r.stderr_w is None or r.fraction_of_nominal is None:
            lines.append(f"| {rank} | {' > '.join(r.surfaces)} | not traced (time cap) | | | | | |")
            continue
        power = f"{r.power_w:.4e}" if r.upper_w is None else f"0 (< {r.upper_w:.1e} at 95 %: no ray arrived)"
        lines.append(f"| {rank} | {' > '.join(r.surfaces)} | {power} | {r.stderr_w:.1e} | "
                     f"{r.fraction_of_nominal:.3e} | {_cell(r.focus_mm)} | {_cell(r.radius_mm)} | "
                     f"{_cell(r.peak_ratio)} |")
    lines += ["", "focus: where the ghost's bundle is narrowest, mm along the light's direction from the detector "
              "(< 0: before it); radius: RMS radius of its spot on the detector; peak ratio: its peak irradiance "
              f"over the nominal image's, both on a {MAP_BINS} x {MAP_BINS} grid over the detector, "
              f"averaged over {PEAK_CELLS} x {PEAK_CELLS} cells (more where so few rays arrive that the block's mean "
              f"is not known to {PEAK_REL_ERROR:.0%}), the block chosen with half the rays and read with the other half."]
    return "\n".join(lines) + "\n"


def plot_maps(table: GhostTable, path, top: int = 8):
    """The nominal image and the ``top`` strongest ghosts as irradiance maps on the detector (W/mm^2, log)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    import atomicio

    labels = ["nominal"] + [r.map_key or " > ".join(r.surfaces) for r in table.rows[:top] if r.power_w is not None]
    n = len(labels)
    cols = min(3, n)
    rows = -(-n // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 3.3 * rows), squeeze=False)
    h = table.half_width_mm
    for ax, lab in zip(axes.ravel(), labels):
        m = table.maps[lab]
        pos = m[m > 0]
        if len(pos):
            ax.set_facecolor("black")
            im = ax.imshow(np.where(m > 0, m, np.nan).T, origin="lower", extent=[-h, h, -h, h], cmap="magma",
                           norm=LogNorm(vmin=max(pos.min(), pos.max() * 1e-6), vmax=pos.max()))
            fig.colorbar(im, ax=ax, shrink=0.8, label="W/mm$^2$")
        row = table.nominal if lab == "nominal" else \
            next(r for r in table.rows if (r.map_key or " > ".join(r.surfaces)) == lab)
        ax.set_title(f"{lab}\n{row.power_w:.2e} W", fontsize=9)
        ax.set_xlabel("u (mm)")
        ax.set_ylabel("v (mm)")
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    fig.suptitle(f"Ghost irradiance at {table.detector} (field {table.field_deg:g} deg)")
    fig.tight_layout()
    out = atomicio.write_figure(fig, path, dpi=110)
    plt.close(fig)
    return out


def ghosts(scene, order: int = 2, field_deg: float = 0.0, detector: str | None = None,
           max_seconds: float | None = None, execution=None, started: float | None = None, **kwargs) -> GhostTable:
    """Notebook API: the ghost table of a scene file (or a loaded scene) at ``field_deg``; ``max_seconds``
    caps the call's wall-clock time (loading the scene and the nominal image's trace included; counted from
    ``started``, a ``monotonic()`` reading, default this call's start), ``execution=Execution(workers=K)`` traces them in K processes (default,
    None: one a core this process may use; ``Execution(workers=1)``: this process) and ``kwargs`` go to
    :func:`ghost_table` (``target_rel_error``, ...)."""
    from straylight.execution import Execution
    from straylight.scene import load_scene

    started = monotonic() if started is None else started
    if execution is None or execution.workers is None:
        execution = Execution(workers=default_workers())

    rs = load_scene(scene) if not hasattr(scene, "scene") else scene
    opt = prepare(rs, field_deg, detector)
    table = ghost_table(opt, order=order, max_seconds=max_seconds, execution=execution, started=started, **kwargs)
    table.field_deg = float(field_deg)
    table.optics = opt
    return table
