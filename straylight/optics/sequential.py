"""The lens file's own sequential trace (rayoptics' real-ray trace, surface by surface in file order), used
to check that an imported scene focuses where the design does (docs/optics.md).

Rays start on the ``pupil`` source's disk (scene frame, mm), travel along (0, sin F, cos F), and are traced
by :func:`rayoptics.raytr.raytrace.trace` from the object surface; a ray is kept where it passes every
surface inside the clear aperture the scene uses (and outside its hole or obscuration).
"""
from __future__ import annotations

import math

import numpy as np

from straylight.optics import aperture
from straylight.optics.sag import sag_mm


def pupil_grid(radius_mm: float, n: int) -> np.ndarray:
    """About ``n`` points (x, y) on a square grid inside a disk of ``radius_mm``."""
    k = max(int(math.sqrt(4.0 * n / math.pi)), 3)
    g = np.linspace(-radius_mm, radius_mm, k)
    x, y = np.meshgrid(g, g)
    inside = x * x + y * y <= radius_mm * radius_mm
    return np.column_stack([x[inside], y[inside]])


def sequential_spot(p, field_deg: float, source_z_mm: float, source_radius_mm: float, n: int = 2000,
                    source_centre_xy=(0.0, 0.0), min_kept: int = 0, max_n: int = 60_000):
    """Global points (mm) where the kept rays cross the image surface, shape (m, 3). ``min_kept``: when fewer
    rays than that pass (a small stop behind a wide source disk), the disk is sampled again with
    proportionally more rays (at most ``max_n``), so the edge of the pupil, where the spot is widest, is
    sampled finely enough (the Nikon 1 Nikkor 10 mm: 69 of 3000 rays pass, r_geo 2.9 um; with 4.4e4 rays, 5.1)."""
    def spot(n_rays):
        paths = sequential_paths(p, field_deg, source_z_mm, source_radius_mm, n_rays, source_centre_xy=source_centre_xy)
        pts = np.array([path[-1] for path in paths]).reshape(-1, 3)
        return pts[np.all(np.isfinite(pts), axis=1)]  # a ray along the image plane (a 90 deg off-axis mirror) meets it nowhere

    pts = spot(n)
    if 0 < len(pts) < min_kept and n < max_n:
        pts = spot(int(min(max_n, n * 1.2 * min_kept / len(pts))))
    return pts


def _crossing(q, a_pt, b_pt):
    """(t, rho, (x, y)) where the segment a_pt -> b_pt crosses surface ``q`` (its sag at the crossing's radius;
    (x, y) in the surface's own frame), or None."""
    ax = q.local_z
    denom = float(np.dot(b_pt - a_pt, ax))
    if abs(denom) < 1e-12:
        return None
    r, t = 0.0, 0.0
    for _ in range(3):
        plane_pt = q.vertex_mm + sag_mm(q, min(r, q.semi_diameter_mm)) * ax
        t = float(np.dot(plane_pt - a_pt, ax)) / denom
        x = a_pt + t * (b_pt - a_pt) - q.vertex_mm
        r = float(np.linalg.norm(x - np.dot(x, ax) * ax))
    length = float(np.linalg.norm(b_pt - a_pt))
    if t * length <= 1e-6 or (1.0 - t) * length <= 1e-6:  # at an end (a coordinate break on the mirror): no crossing
        return None
    return t, r, aperture.local_xy(q, x)


def _coincide(a, b) -> bool:
    """The same physical surface met twice (a Maksutov's secondary spot on the meniscus, a Mangin's glass)."""
    return bool(np.linalg.norm(a.vertex_mm - b.vertex_mm) < 1e-6 and abs(abs(float(np.dot(a.local_z, b.local_z))) - 1) < 1e-9
            and (a.radius_mm or 0.0) == (b.radius_mm or 0.0))


def _real_segments(p, path):
    """(from index, to index, from point, to point) between the surfaces that are parts (dummies and coordinate
    breaks skipped: rayoptics may put their points behind the ray), the source (row 0) and the image (last row)."""
    keep = [0] + [q.index for q in p.surfaces if not q.dummy] + [len(path) - 1]
    return [(a, b, path[a], path[b]) for a, b in zip(keep, keep[1:])]


def _blocked(p, path) -> bool:
    """Whether a sequential ray crosses, between two of its surfaces, another surface's part (a Cassegrain's
    secondary in the incoming beam, a primary outside its hole): the scene stops such a ray, so does this check."""
    for i_from, i_to, a_pt, b_pt in _real_segments(p, path):
        ends = [e for e in p.surfaces if e.index in (i_from, i_to)]
        for q in p.surfaces:
            if q.dummy or q.index in (i_from, i_to) or any(_coincide(q, e) for e in ends):
                continue
            hit = _crossing(q, a_pt, b_pt)
            if hit is None:
                continue
            lo = q.inner_radius_mm if q.inner_kind == "hole" else 0.0
            x_q, y_q = hit[2]
            if aperture.inside(q, x_q, y_q, hole_mm=lo):
                return True
    return False


def sequential_paths(p, field_deg: float, source_z_mm: float, source_radius_mm: float, n: int = 2000,
                     block: bool = True, source_centre_xy=(0.0, 0.0)) -> list:
    """Each kept ray's global points (mm): the start on the source disk, then every surface from the first to the
    image (row k: surface k). ``block``: drop rays that cross another surface's part between two of theirs."""
    from rayoptics.raytr import raytrace as rt

    sm = p.model["seq_model"]
    s = p.scale
    f = math.radians(field_deg)
    d = np.array([0.0, math.sin(f), math.cos(f)])
    rot0, t0 = (np.asarray(a, float) for a in sm.gbl_tfrms[0])
    img_rot, img_t = (np.asarray(a, float) for a in sm.gbl_tfrms[-1])
    limits = {q.index: (q, q.inner_radius_mm if q.inner_kind else 0.0)
              for q in p.surfaces if not q.dummy or q.stop}  # a dummy surface is no part: it stops nothing
    stop = next((q for q in p.surfaces if q.stop), None)
    stop_hole = None
    if stop is not None and not stop.semi_diameter_from_file:  # the black stop's hole (scene_build)
        stop_hole = stop.semi_diameter_mm / 1.05
    out = []
    # a ray that misses a surface comes back from rayoptics as NaN (numpy's divide and invalid warnings on the
    # way): it fails the aperture test below, or is dropped by sequential_spot; no warning for it
    with np.errstate(all="ignore"):
        for x, y in pupil_grid(source_radius_mm, n) + np.asarray(source_centre_xy, float):
            start = np.array([x, y, source_z_mm]) / s
            t = (start[2] - t0[2]) / d[2]
            p0 = rot0.T @ (start - t * d - t0)
            try:
                ray, _, _ = rt.trace(sm, p0, rot0.T @ d, p.wavelength_nm)
            except Exception:  # noqa: BLE001 - missed surface, TIR: the ray does not reach the image
                continue
            ok = True
            for i, seg in enumerate(ray):
                if i in limits:
                    q, lo = limits[i]
                    x_mm, y_mm = seg[0][0] * s, seg[0][1] * s
                    if q is stop and stop_hole is not None:
                        passes = lo <= math.hypot(x_mm, y_mm) <= stop_hole
                    else:
                        passes = aperture.inside(q, x_mm, y_mm, hole_mm=lo)
                    if not passes:
                        ok = False
                        break
            if ok:
                pts = [start * s] + [(np.asarray(sm.gbl_tfrms[i][0], float) @ np.asarray(seg[0], float)
                                      + np.asarray(sm.gbl_tfrms[i][1], float)) * s for i, seg in enumerate(ray) if i >= 1]
                path = np.array(pts)
                if not (block and _blocked(p, path)):
                    out.append(path)
    return out


def holes_for_passing_light(p, source_z_mm: float, source_radius_mm: float, source_centre_xy=(0.0, 0.0),
                            n: int = 600) -> dict:
    """{surface index: radius_mm} of the central hole a mirror needs where the sequential beam, on its way to a
    later surface, crosses the mirror's clear aperture (a Cassegrain primary that the file gives no hole); and a
    lens surface met before a mirror, where the beam after the mirror crosses it in air (no glass can be there)."""
    mirrors = [q for q in p.surfaces if q.mirror]
    if not mirrors:
        return {}
    by_index = {q.index: q for q in p.surfaces}
    lenses = [q for q in p.surfaces if not q.mirror and not q.dummy]
    need: dict = {}
    for field in {0.0, max(p.fields_deg or [0.0])}:
        for path in sequential_paths(p, field, source_z_mm, source_radius_mm, n, block=False,
                                     source_centre_xy=source_centre_xy):
            for i_from, i_to, a_pt, b_pt in _real_segments(p, path)[1:]:  # the incoming beam makes no hole
                # a lens surface met before, crossed by the beam in air after a mirror (the Nikon Reflex-Nikkor
                # 1000 mm's rear group inside its Mangin primary's hole): the glass has a hole there too
                start = by_index.get(i_from)
                in_air = start is not None and abs(start.n - 1.0) < 1e-12
                ends = [by_index[i] for i in (i_from, i_to) if i in by_index]
                for m in mirrors + (lenses if in_air else []):
                    # before the mirror is met, the beam crossing its aperture is obscured by its back (a
                    # secondary's central obscuration, :func:`_blocked`), not passed through a hole
                    if m.index in (i_from, i_to) or i_from < m.index:
                        continue
                    if not m.mirror and (i_from < min(q.index for q in mirrors)
                                         or any(_coincide(m, e) for e in ends)):
                        continue
                    hit = _crossing(m, a_pt, b_pt)
                    if hit and aperture.inside(m, hit[2][0], hit[2][1]):
                        dx, dy = m.aperture_offset_mm  # a hole about the aperture's own centre
                        need[m.index] = max(need.get(m.index, 0.0), math.hypot(hit[2][0] - dx, hit[2][1] - dy))
    return need
