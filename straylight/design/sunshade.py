"""A sunshade that closes what a skirt within the obscuration budget leaves of the direct view.

When the skirt and tube that close every line from the image to the sky (:mod:`straylight.design.shields`)
cost more obscuration than allowed, the widest skirt within the budget is kept and the lines it leaves
open are followed out of the telescope: they pass the tube's rim (|y| <= a at u_p) and then outside the
skirt's mouth (|y| > r_s at u_s), so they leave steeply. In free space the distance of a line from the axis,
|x(u)|, is convex along it, so beyond the mouth |x(u)| >= r_s + (r_s - a)(u - u_s)/(u_s - u_p): every such
line reaches a cylinder of radius R_sh (about the axis, just clear of the field's incoming beam) within a
finite height, and a black cylinder up to there (the sunshade) stops it, while it takes nothing from the
beam of the field. The open lines are the meridional ones (in 3-D they are the worst, docs/baffles.md):
a grid over their two parameters (y at the tube's rim, y at the skirt's mouth), exactly through the
apertures (:func:`straylight.design.shields.max_exit`), is walked upward through the scene's glass (a
Maksutov's meniscus refracts them) with :func:`straylight.design.telescope_model.walk`; where each
escaping one crosses R_sh (solved exactly for the line leaving the last surface) gives the length, plus
``LENGTH_MARGIN`` of it. The sky angles of those lines are returned, for the tracer's direct-path check to
look exactly there.
"""
from __future__ import annotations

import numpy as np

from straylight.design.shields import Sunshade, apertures, margin_mm, max_exit

LENGTH_MARGIN = 0.02  # of the shade's length, for the grid's spacing and the glass's 3-D (skew) refraction
MAX_LENGTH_DIAMETERS = 8.0  # longer than this many aperture diameters is no sunshade: refuse instead


class SunshadeError(ValueError):
    """No sunshade closes the open lines (one-line message)."""


def open_lines(tel, lay, n: int = 25) -> tuple[np.ndarray, np.ndarray]:
    """Meridional lines from the image up the tube that pass outside the skirt's mouth: (y at the mouth,
    slope dy/du), a grid over y at the tube's rim x y at the mouth, plus the least steep line exactly."""
    aps = apertures(tel, lay.tube_bottom_u, lay.tube_radius_mm, lay.tube_top_u, lay.field_stop_radius_mm)
    u_p, a, u_s = lay.tube_top_u, lay.tube_radius_mm, lay.skirt_bottom_u
    r_open = lay.skirt_radius_mm - margin_mm(tel.aperture_radius_mm)  # the construction's own margin
    y_hi = max_exit(aps, u_s)
    if y_hi <= r_open:
        return np.zeros(0), np.zeros(0)
    ys, slopes = [], []
    for yp in np.linspace(-a, a, n):
        for y_s in np.linspace(r_open, y_hi, n):
            k = (y_s - yp) / (u_s - u_p)
            if all(abs(yp + k * (u - u_p)) <= c + 1e-9 for u, c in aps):
                ys.append(y_s)
                slopes.append(k)
    return np.array(ys), np.array(slopes)


def _crossing(p, d, tel, radius_mm):
    """Height u where the line p + t d (t >= 0) reaches ``radius_mm`` from the axis (nan: never)."""
    q = p - tel.origin
    qp = q - np.outer(q @ tel.axis, tel.axis)
    dp = d - np.outer(d @ tel.axis, tel.axis)
    A = np.einsum("ij,ij->i", dp, dp)
    B = 2 * np.einsum("ij,ij->i", qp, dp)
    C = np.einsum("ij,ij->i", qp, qp) - radius_mm ** 2
    disc = B ** 2 - 4 * A * C
    with np.errstate(invalid="ignore", divide="ignore"):
        t = (-B + np.sqrt(disc)) / (2 * A)
    t = np.where((disc >= 0) & (A > 0) & (t >= 0), t, np.nan)
    return (q + t[:, None] * d) @ tel.axis


def _front_u(setup, tel, bundle) -> float:
    """Where the shade starts: the entrance (``[analysis]``) or the highest first hit of the image-forming
    rays (the front of the optics), whichever is higher."""
    firsts = [segs[0][3] for _, segs in bundle.on_axis_segments if segs]
    u = max(firsts) if firsts else tel.secondary_rim_u
    if setup.entrance is not None:
        u = max(u, float(tel.u(setup.entrance.center_mm)))
    return float(u)


def _beam_radius(bundle, u_from, u_to) -> float:
    """The largest distance from the axis of the field's incoming beam between two heights above the
    optics (the incoming rays are straight there: their first segments, extended)."""
    seg = bundle.families["in"]
    first = seg[seg[:, 0] >= u_from]  # segments starting upstream of the optics' front
    if len(first) == 0:
        return 0.0
    u0, y0, u1, y1 = first.T
    k = (y1 - y0) / np.where(np.abs(u1 - u0) > 1e-12, u1 - u0, 1.0)
    return float(max(np.max(np.abs(y0 + k * (u_from - u0))), np.max(np.abs(y0 + k * (u_to - u0)))))


def construct(setup, tel, bundle, lay) -> Sunshade | None:
    """The sunshade that stops the lines ``lay`` leaves open (None when it leaves none open)."""
    from straylight.design.telescope_model import walk

    ys, slopes = open_lines(tel, lay)
    if len(ys) == 0:
        return None
    m = margin_mm(tel.aperture_radius_mm)
    o = np.array([tel.point(lay.skirt_bottom_u, y) for y in ys])
    d = tel.axis[None, :] + slopes[:, None] * tel.e1[None, :]
    d /= np.linalg.norm(d, axis=1)[:, None]
    w = walk(setup.scene, setup.materials, tel.image, o, d)
    assert w.directions is not None and w.stopped is not None
    free = ~w.stopped
    if not np.any(free):
        return None
    last = np.array([w.vertices[i, w.n_hits[i]] for i in np.flatnonzero(free)])
    dirs = w.directions[free]
    u_bot = _front_u(setup, tel, bundle)
    radius = _beam_radius(bundle, u_bot, u_bot) + m
    top = u_bot
    limit = u_bot + MAX_LENGTH_DIAMETERS * 2 * tel.aperture_radius_mm
    for _ in range(6):  # the radius clears the field's beam up to the top, which depends on the radius
        cross = _crossing(last, dirs, tel, radius)
        if not np.all(np.isfinite(cross)):
            raise SunshadeError("a line left open by the skirt does not leave the axis: no sunshade stops it")
        top = float(cross.max())
        top += LENGTH_MARGIN * (top - u_bot) + m
        if top > limit:
            break
        radius = _beam_radius(bundle, u_bot, top) + m
    if top > limit:
        raise SunshadeError(f"a sunshade {top - u_bot:.0f} mm long (more than {MAX_LENGTH_DIAMETERS:g} aperture "
                            "diameters)")
    # every open line must start inside the shade: its distance from the axis at the shade's bottom
    at_bot = last + ((u_bot - tel.u(last)) / (dirs @ tel.axis))[:, None] * dirs
    if np.any(tel.u(last) > u_bot) or np.any(np.linalg.norm(
            (at_bot - tel.origin) - np.outer((at_bot - tel.origin) @ tel.axis, tel.axis), axis=1) >= radius):
        raise SunshadeError("the lines the skirt leaves open pass outside the front of the telescope")
    ang = np.degrees(np.arccos(np.clip(dirs @ tel.axis, -1.0, 1.0)))
    return Sunshade(radius_mm=float(radius), from_u=float(u_bot), to_u=float(top),
                    angles_deg=(float(ang.min()), float(ang.max())), lines=int(free.sum()))
