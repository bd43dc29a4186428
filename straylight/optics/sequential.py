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


#: fixed-point steps on the sag's plane before a crossing is sought by a sign change instead
CROSSING_STEPS = 12
#: points of the sign-change scan along a segment where the fixed point does not settle on the surface
SCAN_POINTS = 65
BISECTIONS = 30  # 2^-30 of a scan step: ~1.5e-11 of the segment


def crossings(q, a_pts, b_pts, start_on_surface: bool = False):
    """Per row, (t, rho, x, y) where the segment a_pts -> b_pts ((n, 3), mm) crosses surface ``q``: t along the
    segment (NaN: no crossing), the radius, and (x, y) in the surface's own frame. ``start_on_surface``: a segment
    leaving from a point on the surface crosses it there (an element cemented in a mirror's centre leaves through
    the mirror's face).

    The crossing is the fixed point of "meet the plane of the sag at the last radius"; where that does not settle
    on the surface inside the segment (a segment steep to a steep surface: the TH Swiss Irix 11 mm's s5 -> s6 rays
    at 55 deg, 0.3 mm in front of s7, all read as crossing it after the 3 steps this took before), the first sign
    change of the axial distance along the segment (:data:`SCAN_POINTS` points), bisected. An end of the segment
    (a coordinate break on a mirror) is no crossing."""
    a_pts = np.atleast_2d(np.asarray(a_pts, dtype=np.float64))
    d = np.atleast_2d(np.asarray(b_pts, dtype=np.float64)) - a_pts
    ax = np.asarray(q.local_z, dtype=np.float64)
    v0 = np.asarray(q.vertex_mm, dtype=np.float64)
    sd = q.semi_diameter_mm
    denom = d @ ax
    length = np.linalg.norm(d, axis=1)
    t = np.full(len(a_pts), np.nan)
    rows = np.flatnonzero(np.abs(denom) >= 1e-12)
    r = np.zeros(len(rows))
    tt = np.zeros(len(rows))
    g = np.full(len(rows), np.inf)
    moving = np.ones(len(rows), dtype=bool)
    for _ in range(CROSSING_STEPS):
        m = np.flatnonzero(moving)
        if len(m) == 0:
            break
        plane_z = sag_mm(q, np.minimum(r[m], sd)) + (v0 - a_pts[rows[m]]) @ ax
        tt[m] = plane_z / denom[rows[m]]
        g[m], r_new = _gap(q, a_pts[rows[m]], d[rows[m]], tt[m])[:2]
        moving[m] = np.abs(r_new - r[m]) > 1e-9 * np.maximum(1.0, r[m])
        r[m] = r_new
    good = ~moving & (np.abs(g) <= 1e-7 * np.maximum(1.0, length[rows]))
    t[rows[good]] = tt[good]
    with np.errstate(invalid="ignore"):
        t[(t * length <= 1e-6) | ((1.0 - t) * length <= 1e-6)] = np.nan
    # no root, or a root off the segment (beyond the aperture the sag is held at its edge's: a segment across a
    # steep surface's edge zone meets that flat extension outside the segment and the surface inside it)
    bad = rows[np.isnan(t[rows])]
    if len(bad):  # a segment whose axial coordinate stays beyond the surface's sag range on one side meets it nowhere
        lo, hi = _sag_range(q)
        z0 = (a_pts[bad] - v0) @ ax
        z1 = z0 + denom[bad]
        bad = bad[~(((z0 < lo) & (z1 < lo)) | ((z0 > hi) & (z1 > hi)))]
    if len(bad):
        t[bad] = _sign_change(q, a_pts[bad], d[bad])
        with np.errstate(invalid="ignore"):
            t[(t * length <= 1e-6) | ((1.0 - t) * length <= 1e-6)] = np.nan
    if start_on_surface:
        g0 = _gap(q, a_pts, d, np.zeros(len(a_pts)))[0]
        t[(np.abs(g0) <= 1e-6) & (length > 1e-6)] = 0.0
    _, rho, rel = _gap(q, a_pts, d, np.nan_to_num(t))
    x_axis, y_axis = aperture.axes(q)
    nan = np.isnan(t)
    return t, np.where(nan, np.nan, rho), np.where(nan, np.nan, rel @ x_axis), np.where(nan, np.nan, rel @ y_axis)


def _sag_range(q) -> tuple[float, float]:
    """(lowest, highest) sag of surface ``q`` over its semi-diameter (257 radii), widened by 1 % of the range (the sag
    between two sampled radii) and 1e-9 of its size."""
    sag = sag_mm(q, np.linspace(0.0, q.semi_diameter_mm, 257))
    pad = 0.01 * float(sag.max() - sag.min()) + 1e-9 * max(1.0, q.semi_diameter_mm, float(np.abs(sag).max()))
    return float(sag.min()) - pad, float(sag.max()) + pad


def _gap(q, a_pts, d, t):
    """Per row (and column of a 2-D ``t``), (axial distance from surface ``q``, radius, vector from its vertex) of
    the point a + t d."""
    ax = np.asarray(q.local_z, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    lead = (len(a_pts),) + (1,) * (t.ndim - 1) + (3,)
    rel = a_pts.reshape(lead) + t[..., None] * d.reshape(lead) - np.asarray(q.vertex_mm, dtype=np.float64)
    z = rel @ ax
    perp = rel - z[..., None] * ax
    r = np.sqrt(np.einsum("...i,...i->...", perp, perp))
    return z - sag_mm(q, np.minimum(r, q.semi_diameter_mm)), r, rel


def _sign_change(q, a_pts, d) -> np.ndarray:
    """Per row, the first t in [0, 1] where the axial distance of a + t d from surface ``q`` changes sign (bisected
    to ~1e-11 of the segment), NaN where it does not."""
    m = len(a_pts)
    ts = np.linspace(0.0, 1.0, SCAN_POINTS)
    g = _gap(q, a_pts, d, np.broadcast_to(ts, (m, SCAN_POINTS)))[0]
    change = (g[:, :-1] == 0.0) | (g[:, :-1] * g[:, 1:] < 0.0)
    out = np.full(m, np.nan)
    rows = np.flatnonzero(change.any(axis=1))
    if len(rows) == 0:
        return out
    k = np.argmax(change[rows], axis=1)
    lo, hi = ts[k], ts[k + 1]
    g_lo = g[rows, k]
    exact = g_lo == 0.0
    a_pts, d = a_pts[rows], d[rows]
    for _ in range(BISECTIONS):
        mid = 0.5 * (lo + hi)
        g_mid = _gap(q, a_pts, d, mid)[0]
        same = (g_mid < 0.0) == (g_lo < 0.0)
        lo, g_lo, hi = np.where(same, mid, lo), np.where(same, g_mid, g_lo), np.where(same, hi, mid)
    out[rows] = np.where(exact, ts[k], 0.5 * (lo + hi))
    return out


def _coincide(a, b) -> bool:
    """The same physical surface met twice (a Maksutov's secondary spot on the meniscus, a Mangin's glass)."""
    return bool(np.linalg.norm(a.vertex_mm - b.vertex_mm) < 1e-6 and abs(abs(float(np.dot(a.local_z, b.local_z))) - 1) < 1e-9
            and (a.radius_mm or 0.0) == (b.radius_mm or 0.0))


def _real_segments(p, n_points: int):
    """(from index, to index) of a path's points between the surfaces that are parts (dummies and coordinate
    breaks skipped: rayoptics may put their points behind the ray), the source (row 0) and the image (the last of
    ``n_points`` rows)."""
    keep = [0] + [q.index for q in p.surfaces if not q.dummy] + [n_points - 1]
    return list(zip(keep, keep[1:]))


def _blocked(p, paths: np.ndarray) -> np.ndarray:
    """Per path ((m, surfaces + 1, 3)), whether the sequential ray crosses, between two of its surfaces, another
    surface's part (a Cassegrain's secondary in the incoming beam, a primary outside its hole): the scene stops
    such a ray, so does this check."""
    out = np.zeros(len(paths), dtype=bool)
    for i_from, i_to in _real_segments(p, paths.shape[1]):
        ends = [e for e in p.surfaces if e.index in (i_from, i_to)]
        for q in p.surfaces:
            if q.dummy or q.index in (i_from, i_to) or any(_coincide(q, e) for e in ends):
                continue
            t, _, x_q, y_q = crossings(q, paths[:, i_from], paths[:, i_to])
            lo = q.inner_radius_mm if q.inner_kind == "hole" else 0.0
            hit = ~np.isnan(t)
            out[hit] |= aperture.inside(q, x_q[hit], y_q[hit], hole_mm=lo)
    return out


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
                out.append(np.array(pts))
    if block and out:
        blocked = _blocked(p, np.stack(out))
        out = [path for path, b in zip(out, blocked) if not b]
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
    where: dict = {}  # {surface index: the crossings' (x, y) about its aperture's centre}
    for field in {0.0, max(p.fields_deg or [0.0])}:
        kept = sequential_paths(p, field, source_z_mm, source_radius_mm, n, block=False,
                                source_centre_xy=source_centre_xy)
        if not kept:
            continue
        paths = np.stack(kept)
        for i_from, i_to in _real_segments(p, paths.shape[1])[1:]:  # the incoming beam makes no hole
            # a lens surface met before, crossed by the beam in air after a mirror (the Nikon Reflex-Nikkor
            # 1000 mm's rear group inside its Mangin primary's hole): the glass has a hole there too
            start = by_index.get(i_from)
            in_air = start is not None and abs(start.n - 1.0) < 1e-12
            ends = [by_index[i] for i in (i_from, i_to) if i in by_index]
            for m in mirrors + lenses:
                # or in a glass that is on neither side of the lens surface (US 5331467's rear element, in its own
                # glass, across the Mangin primary's front): no glass of that surface can be there
                foreign = start is not None and all(abs(start.n - index) > 1e-9 for index in (m.n, m.n_before))
                if not m.mirror and not (in_air or foreign):
                    continue
                # before the mirror is met, the beam crossing its aperture is obscured by its back (a
                # secondary's central obscuration, :func:`_blocked`), not passed through a hole
                if m.index in (i_from, i_to) or i_from < m.index:
                    continue
                if not m.mirror and (i_from < min(q.index for q in mirrors) or any(_coincide(m, e) for e in ends)):
                    continue
                # a start on the surface leaves through it
                t, _, x, y = crossings(m, paths[:, i_from], paths[:, i_to], start_on_surface=True)
                hit = ~np.isnan(t)
                hit[hit] = aperture.inside(m, x[hit], y[hit])
                if hit.any():
                    dx, dy = m.aperture_offset_mm  # a hole about the aperture's own centre
                    rel = np.column_stack([x[hit] - dx, y[hit] - dy])
                    need[m.index] = max(need.get(m.index, 0.0), float(np.hypot(rel[:, 0], rel[:, 1]).max()))
                    where.setdefault(m.index, []).append(rel)
    # a hole is where a later beam passes through the surface's centre (a Cassegrain primary), not where it grazes
    # one side of its aperture (HoO-V2C18Ex66: the s7 -> s11 beam crosses s3's at 14.6 of 16.0 mm, on one side;
    # a hole of that radius took all of s3's own beam)
    return {i: r for i, r in need.items() if np.linalg.norm(np.concatenate(where[i]).mean(axis=0)) <= 0.5 * r}
