"""A two-mirror telescope read from its scene: which parts are the primary, the secondary and the
image, and the exact nominal ray bundle (edge rays of the field) that the baffles must not touch.

The parts are recognised by what they do, not by their names: an on-axis fan from the scene's
``collimated_disk`` source is walked through the exact analytic surfaces (CONTRACTS 6.1: mirrors
reflect, ``dielectric`` surfaces refract by Snell's law, n1 sin t1 = n2 sin t2, Born & Wolf 1.5.1;
everything else stops the ray); the first mirror the image-forming rays meet is the primary, the
second the secondary. Frame used by the construction (:mod:`straylight.design.shields`): ``u`` along
the axis from the primary's vertex toward the secondary's, ``y`` the meridional coordinate.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from materials.smooth import reflect, refract


class TelescopeError(ValueError):
    """The scene is not a two-mirror telescope the baffle design understands (one-line message)."""


def _components(material) -> list:
    return list(getattr(material, "components", None) or ())


def _kind(part, materials) -> str:
    """``mirror``, ``glass`` (index in ``_index``), ``detector`` or ``stop`` (absorbs)."""
    if part.role == "detector":
        return "detector"
    if part.role == "mirror":
        return "mirror"
    if part.role == "absorber" or part.material is None:
        return "stop"
    names = {type(c).__name__ for c in _components(materials.get(part.material))}
    if "Specular" in names:
        return "mirror"
    if "Dielectric" in names:
        return "glass"
    return "stop"


def _index(part, materials) -> float:
    for c in _components(materials.get(part.material)):
        if type(c).__name__ == "Dielectric":
            n = c.n
            return float(n[0] if isinstance(n, (tuple, list, np.ndarray)) else n)
    return 1.0


@dataclass
class Walk:
    """Rays walked through the scene: vertices (n, k+1, 3) padded with nan, hit part index per
    vertex (-1: none), the number of hits, and whether the last hit was the detector."""

    vertices: np.ndarray
    parts: np.ndarray
    n_hits: np.ndarray
    detected: np.ndarray
    directions: np.ndarray | None = None  # (n, 3) each ray's direction after its last hit
    stopped: np.ndarray | None = None     # (n,) whether the ray ended on a part (not in free space)


def walk(scene, materials, detector: str, o, d, max_hits: int = 8) -> Walk:
    """Exact specular walk (mirrors reflect on their front, glass refracts, all else stops)."""
    from straylight.intersect import EmbreeIntersector

    o = np.array(o, float)
    d = np.array(d, float)
    n = len(o)
    kinds = [_kind(p, materials) for p in scene.parts]
    index = [_index(p, materials) for p in scene.parts]
    det = scene.part_names.index(scene.resolve(detector))
    tri_part = scene.triangle_part
    isect = EmbreeIntersector(scene.triangles_mm)
    bounds = np.asarray(scene.bounds_mm, float)
    scale = float(np.linalg.norm(bounds[1] - bounds[0]))
    verts = np.full((n, max_hits + 1, 3), np.nan)
    verts[:, 0] = o
    parts = np.full((n, max_hits + 1), -1)
    nh = np.zeros(n, int)
    detected = np.zeros(n, bool)
    alive = np.ones(n, bool)
    stopped = np.zeros(n, bool)
    last = np.full(n, -1)
    for k in range(max_hits):
        idx = np.flatnonzero(alive)
        if len(idx) == 0:
            break
        start = o[idx] + 1e-7 * d[idx]
        tri, t = isect.intersect(start, d[idx])
        # a ray leaving an exact surface may meet that surface's own mesh a chord away: step past it
        for _ in range(5):
            again = (tri >= 0) & (tri_part[np.maximum(tri, 0)] == last[idx]) & (t < 1e-3 * scale)
            if not np.any(again):
                break
            sel = np.flatnonzero(again)
            skip = t[sel] + 1e-6 * scale
            tri2, t2 = isect.intersect(start[sel] + skip[:, None] * d[idx[sel]], d[idx[sel]])
            tri[sel], t[sel] = tri2, np.where(tri2 >= 0, t2 + skip, t2)
        hit = tri >= 0
        alive[idx[~hit]] = False
        idx, t, start = idx[hit], t[hit], start[hit]
        part = tri_part[tri[hit]]
        for pi in np.unique(part):
            sel = part == pi
            rows = idx[sel]
            p = scene.parts[pi]
            if p.surface is not None:
                tr, nrm, ok = p.surface.refine_hits(start[sel], d[rows], t[sel])
                ok = ok & np.isfinite(tr)
                tr = np.where(ok, tr, t[sel])
            else:  # a mesh: the triangle's hit, the flat normal facing the ray
                tr = t[sel]
                nrm = -d[rows]
                ok = np.ones(len(rows), bool)
            if not np.any(ok):
                continue
            rows, tr, nrm = rows[ok], tr[ok], nrm[ok]
            o[rows] = start[sel][ok] + tr[:, None] * d[rows]
            verts[rows, k + 1] = o[rows]
            parts[rows, k + 1] = pi
            nh[rows] = k + 1
            last[rows] = pi
            front = np.einsum("ij,ij->i", d[rows], nrm) < 0
            kind = kinds[pi]
            if pi == det:
                detected[rows[front]] = True
                alive[rows] = False
                stopped[rows] = True
            elif kind == "mirror":
                d[rows[front]] = reflect(d[rows[front]], nrm[front])
                alive[rows[~front]] = False
                stopped[rows[~front]] = True
            elif kind == "glass":
                nn = np.where(front[:, None], nrm, -nrm)
                eta = np.where(front, 1.0 / index[pi], index[pi])
                cos_i = -np.einsum("ij,ij->i", d[rows], nn)
                s2 = eta ** 2 * (1.0 - cos_i ** 2)
                tir = s2 > 1.0
                cos_t = np.sqrt(np.maximum(0.0, 1.0 - s2))
                d[rows[~tir]] = refract(d[rows[~tir]], nn[~tir], eta[~tir], cos_t[~tir])
                alive[rows[tir]] = False
                stopped[rows[tir]] = True
            else:
                alive[rows] = False
                stopped[rows] = True
    stopped |= alive  # still bouncing after max_hits: not known to escape
    return Walk(verts, parts, nh, detected, d, stopped)


@dataclass
class Telescope:
    """The two-mirror telescope of a scene, in the frame (u along ``axis`` from ``origin``, y along ``e1``)."""

    primary: str
    secondary: str
    image: str
    origin: np.ndarray
    axis: np.ndarray
    e1: np.ndarray
    image_u: float
    image_radius_mm: float
    primary_outer_mm: float
    primary_hole_mm: float
    primary_hole_u: float
    primary_rim_u: float
    secondary_outer_mm: float
    secondary_rim_u: float
    aperture_radius_mm: float
    beam_axis: np.ndarray
    beam_center: np.ndarray
    beam_radius_mm: float
    extra: dict = field(default_factory=dict)

    def u(self, p):
        return (np.asarray(p, float) - self.origin) @ self.axis

    def y(self, p):
        return (np.asarray(p, float) - self.origin) @ self.e1

    def point(self, u, y=0.0):
        return self.origin + u * self.axis + y * self.e1

    def to_dict(self) -> dict:
        return {"primary": self.primary, "secondary": self.secondary, "image": self.image,
                "axis": [float(v) for v in self.axis], "primary_vertex_mm": [float(v) for v in self.origin],
                "aperture_radius_mm": self.aperture_radius_mm, "primary_outer_radius_mm": self.primary_outer_mm,
                "primary_hole_radius_mm": self.primary_hole_mm, "secondary_outer_radius_mm": self.secondary_outer_mm,
                "image_radius_mm": self.image_radius_mm, "image_distance_mm": self.image_u}


def _perp(w):
    a = np.eye(3)[int(np.argmin(np.abs(w)))]
    e = a - (a @ w) * w
    return e / np.linalg.norm(e)


def fan(tel_or_beam, field_rad: float, n: int, radius_scale: float = 1.0, back_mm: float = 0.0):
    """Meridional rays of a collimated beam at field angle ``field_rad`` (tilted toward +e1) through the
    beam's source disk, starting ``back_mm`` before it (a source placed 1 mm before a lens's vertex may
    lie behind the lens's rim): origins (n, 3), dirs (n, 3), y (n,) across the disk."""
    b, c, e1, R = tel_or_beam
    dvec = math.cos(field_rad) * b + math.sin(field_rad) * e1
    y = np.linspace(-R * radius_scale, R * radius_scale, n)
    p = c[None, :] + y[:, None] * e1[None, :] - back_mm * dvec[None, :]
    return p, np.tile(dvec, (n, 1)), y


def _extent(scene) -> float:
    """The scene's bounding-box diagonal (mm)."""
    b = np.asarray(scene.bounds_mm, float)
    return float(np.linalg.norm(b[1] - b[0]))


def _rim_u(surface, radius_mm: float, tel_origin, axis) -> float:
    sag = float(surface.sag(radius_mm)) if hasattr(surface, "sag") else 0.0
    local = np.array([[radius_mm, 0.0, sag]])
    return float((surface.to_world(local)[0] - tel_origin) @ axis)


def identify(setup, n_rays: int = 801) -> Telescope:
    """Find the primary, secondary and image of ``setup`` (a straylight.analyses.types.Setup)."""
    scene, materials = setup.scene, setup.materials
    det = setup.detector
    beam = setup.beam
    b = np.asarray(beam.axis, float)
    b = b / np.linalg.norm(b)
    c = np.asarray(beam.center_mm, float)
    e1 = _perp(b)
    o, d, y = fan((b, c, e1, float(beam.radius_mm)), 0.0, n_rays, back_mm=_extent(scene))
    w = walk(scene, materials, det, o, d)
    kinds = [_kind(p, materials) for p in scene.parts]
    firsts: dict[int, int] = {}  # part -> rays whose first mirror it is
    seconds: dict[int, int] = {}
    for i in np.flatnonzero(w.detected):
        mirrors = [p for p in w.parts[i, 1:w.n_hits[i] + 1] if p >= 0 and kinds[p] == "mirror"]
        if len(mirrors) >= 2:
            firsts[mirrors[0]] = firsts.get(mirrors[0], 0) + 1
            seconds[mirrors[1]] = seconds.get(mirrors[1], 0) + 1
    if not firsts:
        raise TelescopeError(f"no on-axis ray from the source reaches the detector {det!r} after two mirrors: "
                             "not a two-mirror telescope (mirrors are parts with a 'specular' material)")
    ip = max(firsts, key=lambda p: firsts[p])
    isec = max(seconds, key=lambda p: seconds[p])
    P, S, D = scene.parts[ip], scene.parts[isec], scene.part(det)
    for part in (P, S):
        if part.surface is None or not hasattr(part.surface, "outer_radius_mm"):
            raise TelescopeError(f"mirror {part.name!r} is not an analytic conic surface (CONTRACTS 6.1)")
    origin = np.asarray(P.surface.vertex_mm, float)
    axis = np.asarray(S.surface.vertex_mm, float) - origin
    if np.linalg.norm(axis) < 1e-9:  # the secondary is a spot at the primary's vertex? use the beam
        axis = -b
    axis = axis / np.linalg.norm(axis)
    e1 = _perp(axis)
    if D.surface is not None and hasattr(D.surface, "outer_radius_mm"):
        image_u = float((np.asarray(D.surface.vertex_mm, float) - origin) @ axis)
        image_r = float(D.surface.outer_radius_mm)
    else:
        v = np.asarray(D.vertices_mm, float) - origin
        us = v @ axis
        image_u = float(us.mean())
        image_r = float(np.linalg.norm(v - us[:, None] * axis, axis=1).max())
    yy = np.abs(y[w.detected])
    tel = Telescope(
        primary=P.name, secondary=S.name, image=D.name, origin=origin, axis=axis, e1=e1,
        image_u=image_u, image_radius_mm=image_r,
        primary_outer_mm=float(P.surface.outer_radius_mm), primary_hole_mm=float(P.surface.inner_radius_mm),
        primary_hole_u=_rim_u(P.surface, float(P.surface.inner_radius_mm), origin, axis),
        primary_rim_u=_rim_u(P.surface, float(P.surface.outer_radius_mm), origin, axis),
        secondary_outer_mm=float(S.surface.outer_radius_mm),
        secondary_rim_u=_rim_u(S.surface, float(S.surface.outer_radius_mm), origin, axis),
        aperture_radius_mm=float(yy.max()), beam_axis=b, beam_center=c, beam_radius_mm=float(beam.radius_mm))
    tel.extra["indices"] = (ip, isec, scene.part_names.index(D.name))
    # a spot secondary on a corrector (Maksutov, Schmidt-Cassegrain): a glass surface shares its vertex
    tel.extra["secondary_on_glass"] = any(
        kinds[k] == "glass" and p.surface is not None and hasattr(p.surface, "vertex_mm")
        and float(np.linalg.norm(np.asarray(p.surface.vertex_mm, float) - np.asarray(S.surface.vertex_mm, float)))
        <= 1e-6 * max(tel.aperture_radius_mm, 1.0)
        for k, p in enumerate(scene.parts))
    return tel


@dataclass
class Bundle:
    """Nominal segments in the (u, y) plane, by family: ``in`` (sky to primary), ``ps`` (primary to
    secondary), ``si`` (secondary to image). Each: (m, 4) rows u0, y0, u1, y1."""

    families: dict
    on_axis_y: np.ndarray      # entrance heights of the on-axis fan
    on_axis_nominal: np.ndarray  # which of them form the image (primary, then secondary, then image)
    on_axis_segments: list     # per on-axis ray: list of (family, u0, y0, u1, y1)
    keys: dict = field(default_factory=dict)  # per family segment: the ray's |y| where it crosses the
    #                                           secondary's rim plane going in (inf: does not cross it)
    field_image_radius_mm: float = 0.0  # the largest |y| of the field's image-forming rays on the image plane
    off_detector: int = 0  # how many of them cross the image plane outside the detector disk


def _to_image_plane(pts, direction, stopped, after, tel, kinds, parts):
    """A ray's vertices up to where it crosses the image plane (u = ``tel.image_u``) after the vertex
    ``after`` (the secondary's), passing only glass on the way; None when it does not get there (a stop or
    another mirror first: the telescope itself vignettes it). The walk stops rays only on the detector
    disk; this is for the ones that miss it, whose image falls outside a detector smaller than the field's."""
    u = (pts - tel.origin) @ tel.axis
    side = u[after] - tel.image_u
    if side == 0.0:
        return None
    for j in range(after, len(pts)):
        if j > after and kinds[parts[j]] != "glass":
            return None  # the ray met a stop or a mirror before the plane
        if j + 1 < len(pts):
            d, length = pts[j + 1] - pts[j], 1.0
        elif not stopped:
            d, length = direction, math.inf  # the free ray after the last surface
        else:
            return None
        du = float(d @ tel.axis)
        if du == 0.0:
            continue
        t = (tel.image_u - u[j]) / du
        if 0.0 <= t <= length:
            return np.concatenate([pts[:j + 1], (pts[j] + t * d)[None, :]])
    return None


def nominal_bundle(setup, tel: Telescope, field_deg: float, n_rays: int = 601, n_fields: int = 9) -> Bundle:
    """The image-forming rays of fields -F..F (meridional fans over the whole source disk): those that
    reflect from the primary and then the secondary and reach the image plane, on the detector disk or
    off it (a detector smaller than the field's image must not make the shields narrower than the field's
    beam: they would vignette the field inside F). A ray off the detector counts only when it met the
    same surfaces, in the same order, as a ray that lands on it: a ray that skips a corrector (outside a
    Maksutov's meniscus, onto the primary and the spot) is no part of the image."""
    ip, isec, idet = tel.extra["indices"]
    kinds = [_kind(p, setup.materials) for p in setup.scene.parts]
    image_radius, off_detector = 0.0, 0
    fams: dict[str, list] = {"in": [], "ps": [], "si": []}
    keys: dict[str, list] = {"in": [], "ps": [], "si": []}
    cap_u = tel.secondary_rim_u
    on_y: np.ndarray | None = None
    on_nom: np.ndarray | None = None
    on_segs = []
    fields = np.linspace(-field_deg, field_deg, n_fields) if field_deg > 0 else np.array([0.0])
    fields = np.unique(np.concatenate([fields, [0.0]]))
    walks = []
    for f in fields:
        n = 2001 if f == 0.0 else n_rays
        o, d, y = fan((tel.beam_axis, tel.beam_center, tel.e1, tel.beam_radius_mm), math.radians(f), n,
                      back_mm=_extent(setup.scene))
        walks.append((f, n, y, walk(setup.scene, setup.materials, tel.image, o, d)))
    # the sequences of surfaces (detector left out) of the rays that form the image on the detector
    imaging = {tuple(w.parts[i, 1:w.n_hits[i]]) for _, _, _, w in walks for i in np.flatnonzero(w.detected)}
    for f, n, y, w in walks:
        assert w.directions is not None and w.stopped is not None
        nominal = np.zeros(n, bool)
        for i in range(n):
            seq = list(w.parts[i, 1:w.n_hits[i] + 1])
            if ip not in seq or isec not in seq:
                continue
            kp, ks = seq.index(ip), seq.index(isec)
            if ks < kp:
                continue
            pts = w.vertices[i, :w.n_hits[i] + 1]
            if not w.detected[i]:
                pts = _to_image_plane(pts, w.directions[i], w.stopped[i], ks + 1, tel, kinds, w.parts[i])
                if pts is None or tuple(w.parts[i, 1:len(pts) - 1]) not in imaging:
                    continue
                off_detector += 1
            nominal[i] = True
            image_radius = max(image_radius, abs(float((pts[-1] - tel.origin) @ tel.e1)))
            u = (pts - tel.origin) @ tel.axis
            yy = (pts - tel.origin) @ tel.e1
            segs = []
            key = math.inf
            for j in range(kp + 1):  # where the incoming ray crosses the plane of the secondary's rim
                if min(u[j], u[j + 1]) <= cap_u <= max(u[j], u[j + 1]) and abs(u[j + 1] - u[j]) > 1e-12:
                    key = min(key, abs(yy[j] + (yy[j + 1] - yy[j]) * (cap_u - u[j]) / (u[j + 1] - u[j])))
            for j in range(len(pts) - 1):
                fam = "in" if j < kp + 1 else ("ps" if j < ks + 1 else "si")
                fams[fam].append((u[j], yy[j], u[j + 1], yy[j + 1]))
                keys[fam].append(key)
                segs.append((fam, u[j], yy[j], u[j + 1], yy[j + 1]))
            if f == 0.0:
                on_segs.append((i, segs))
        if f == 0.0:
            on_y, on_nom = y, nominal
    arr = {k: np.asarray(v, float).reshape(-1, 4) for k, v in fams.items()}
    assert on_y is not None and on_nom is not None  # the field list always holds 0
    return Bundle(arr, on_y, on_nom, on_segs, {k: np.asarray(v, float) for k, v in keys.items()},
                  field_image_radius_mm=image_radius, off_detector=off_detector)
