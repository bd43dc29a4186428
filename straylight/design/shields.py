"""Exact construction of a two-mirror telescope's light shields from the edge rays of the field.

The classical layout (Young, Appl. Opt. 6, 1063 (1967); Breault, Handbook of Optics vol. II ch. 38):

- ``baffle_secondary``: a skirt (cylinder of radius r_s) hanging from the secondary's rim toward the
  primary down to u_s, closed at the top by ``baffle_secondary_cap`` (the annulus between the
  mirror's rim and the skirt);
- ``baffle_primary``: a tube of radius a about the axis, from the image plane up to u_p (through the
  primary's hole; ``baffle_primary_collar`` closes the hole around it when a is smaller);
- ``baffle_field_stop``: an annulus closing the tube's bottom, just above the image, from the beam of
  the field (the image of the half-field F, plus aberrations and clearance) out to the tube: only the
  field's image sees up the tube, not the whole detector disk;
- ``baffle_rear``: a cylinder at the primary's rim down past the image plane, so the detector sees
  the sky only through the tube.

Constraints, all exact in the meridional plane (u along the axis, y across it), for the nominal
rays of every field angle in [-F, F] (:func:`straylight.design.telescope_model.nominal_bundle`):

1. the tube must not touch the converging beam (secondary to image): a > max |y| of that beam over
   the tube's height, and it must not touch the rays going to or from the primary;
2. the skirt must not touch the beam primary -> secondary or secondary -> image: r_s > their max |y|
   over [u_s, rim]; so a wider skirt may hang lower;
3. no direct path: every line that leaves the detector disk (|y| <= h at u_i) and passes the tube's
   apertures (|y| <= b at the field stop, |y| <= a at the tube's bottom and rim) must enter the skirt's
   mouth: max y(u_s) <= r_s, a linear programme in the line's two parameters whose optimum is a line
   through two of the apertures' edges on opposite sides (:func:`max_exit`; without a field stop,
   y(u_s) = -a + 2a (u_s - u_b)/(u_p - u_b) for a <= h). In 3-D the meridional line is the worst: for a
   line x(u) (transverse position) the meridional line through -|x(u_j)| and +|x(u_k)| stays within
   |x(u)| between them (reverse triangle inequality) and reaches |x(u_s)| beyond (|(1-t)p + tq| <=
   (t-1)|p| + t|q| for t > 1).

Among the layouts that satisfy all three (a grid over r_s and u_p, each with its least a and its
lowest u_s), the one with the smallest skirt (least added obscuration) is kept, then the largest
margin in (3). The added obscuration is the on-axis entrance area the skirt and tube block beyond
what the unbaffled telescope already loses, over the aperture's area.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


class NoShieldError(ValueError):
    """No layout blocks every direct path within the allowed obscuration (one-line message);
    ``smallest_added``: what the least-obscuring closing layout adds, when there is one."""

    smallest_added: float | None = None


def clipped_abs_range(seg: np.ndarray, lo: float, hi: float):
    """For segments (m, 4) = u0, y0, u1, y1: max and min of |y| over the part with lo <= u <= hi
    (nan where a segment does not reach that range)."""
    if len(seg) == 0:
        return np.zeros(0), np.zeros(0)
    u0, y0, u1, y1 = seg.T
    ua, ub = np.minimum(u0, u1), np.maximum(u0, u1)
    a, b = np.maximum(ua, lo), np.minimum(ub, hi)
    inside = a <= b
    du = np.where(np.abs(u1 - u0) > 1e-12, u1 - u0, 1.0)
    flat = np.abs(u1 - u0) <= 1e-12

    def y_at(u):
        return np.where(flat, y0, y0 + (y1 - y0) * (u - u0) / du)

    ya, yb = y_at(a), y_at(b)
    ya = np.where(flat, y0, ya)
    yb = np.where(flat, y1, yb)
    ymax = np.maximum(np.abs(ya), np.abs(yb))
    ymin = np.where(ya * yb <= 0, 0.0, np.minimum(np.abs(ya), np.abs(yb)))
    return np.where(inside, ymax, np.nan), np.where(inside, ymin, np.nan)


def max_exit(apertures, u_exit: float) -> float:
    """The largest y at ``u_exit`` of a line in the (u, y) plane that passes every aperture: |y(u_k)| <= c_k
    for ``apertures`` = [(u_k, c_k)], at least two distinct heights, all below ``u_exit``. A linear
    programme in two unknowns: its optimum is a vertex, a line through two apertures' edges, so every
    pair of edges is tried and the feasible lines kept (exact)."""
    best = -math.inf
    pts = [(float(u), float(c)) for u, c in apertures]
    for i, (uj, cj) in enumerate(pts):
        for uk, ck in pts[i + 1:]:
            if abs(uk - uj) < 1e-12:
                continue
            for yj in (-cj, cj):
                for yk in (-ck, ck):
                    slope = (yk - yj) / (uk - uj)
                    if all(abs(yj + slope * (ul - uj)) <= cl + 1e-9 for ul, cl in pts):
                        best = max(best, yj + slope * (u_exit - uj))
    return best


def _nanmax(x, default=0.0):
    x = x[np.isfinite(x)]
    return float(x.max()) if len(x) else default


def _nanmin(x, default=math.inf):
    x = x[np.isfinite(x)]
    return float(x.min()) if len(x) else default


@dataclass
class Sunshade:
    """A cylinder about the axis from the front of the telescope (built by straylight.design.sunshade)."""

    radius_mm: float
    from_u: float
    to_u: float
    angles_deg: tuple[float, float]  # the sky angles of the lines it stops (least, steepest)
    lines: int                       # open lines followed (those the telescope itself does not stop)


@dataclass
class Layout:
    skirt_radius_mm: float
    skirt_bottom_u: float
    tube_radius_mm: float
    tube_top_u: float
    tube_bottom_u: float
    cap_u: float
    collar: bool
    rear_radius_mm: float
    rear_from_u: float
    rear_to_u: float
    direct_margin_mm: float
    field_stop_radius_mm: float | None = None  # inner radius of the annulus at the tube's bottom
    sunshade: Sunshade | None = None  # built by straylight.design.sunshade: closes what the skirt leaves open
    obscuration_before: float = 0.0
    obscuration_after: float = 0.0
    notes: list = field(default_factory=list)


def obscuration(tel, bundle, layout: Layout | None) -> float:
    """Fraction of the on-axis aperture (disk of the aperture radius) that does not form the image:
    the unbaffled telescope's own loss (secondary, hole) plus, with ``layout``, what its skirt and
    tube block. Area weights |y| over the meridional fan (an annulus per ray)."""
    y = bundle.on_axis_y
    wgt = np.abs(y) * (np.abs(y) <= tel.aperture_radius_mm)
    ok = bundle.on_axis_nominal.copy()
    if layout is not None:
        for i, segs in bundle.on_axis_segments:
            incoming = np.array([s[1:] for s in segs if s[0] == "in"], float).reshape(-1, 4)
            _, smin = clipped_abs_range(incoming, layout.skirt_bottom_u, layout.cap_u)
            _, tmin = clipped_abs_range(incoming, layout.tube_bottom_u, layout.tube_top_u)
            to_sec = np.array([s[1:] for s in segs if s[0] == "ps"], float).reshape(-1, 4)
            _, pmin = clipped_abs_range(to_sec, layout.tube_bottom_u, layout.tube_top_u)
            if (_nanmin(smin) <= layout.skirt_radius_mm or _nanmin(tmin) <= layout.tube_radius_mm
                    or _nanmin(pmin) <= layout.tube_radius_mm):
                ok[i] = False
    total = wgt.sum()
    return float(1.0 - (wgt * ok).sum() / total) if total > 0 else 0.0


def margin_mm(aperture_radius_mm: float) -> float:
    """Clearance between a shield and the nominal beam, and in the direct-path condition: 0.2 % of the
    aperture radius (at least 0.02 mm). The STEP solids are this thick, so they stay inside it."""
    return max(2e-3 * aperture_radius_mm, 0.02)


class _Suffix:
    """max (or min) of |y| over a u-range for the rays a cap of radius r does not already block.

    The cap annulus (secondary's rim to skirt radius r, at the rim's height) stops every incoming ray that
    crosses that plane inside r, so those rays never reach the primary, the secondary or the image and
    need no clearance. Columns are sorted by that crossing radius (``Bundle.keys``); a reverse cumulative
    max / min gives the value over the rays kept for any r in one lookup."""

    def __init__(self, seg, keys, lo, hi, which):
        order = np.argsort(keys, kind="stable")
        self.keys = keys[order]
        vmax, vmin = clipped_abs_range(seg[order], lo, hi)
        v = vmax if which == "max" else vmin
        acc = np.fmax if which == "max" else np.fmin
        if v.shape[-1]:
            v = acc.accumulate(v[:, ::-1], axis=1)[:, ::-1]
        self.v = np.concatenate([v, np.full((v.shape[0], 1), np.nan)], axis=1)

    def at(self, r_min: float) -> np.ndarray:
        """The values (one per grid height) over the rays whose crossing radius is >= r_min."""
        return self.v[:, int(np.searchsorted(self.keys, r_min, "left"))]


def _fam(bundle, names) -> tuple[np.ndarray, np.ndarray]:
    seg = np.concatenate([bundle.families[k] for k in names])
    keys = [bundle.keys.get(k) if bundle.keys else None for k in names]
    found = [k for k in keys if k is not None]
    if len(found) < len(keys):
        return seg, np.full(len(seg), np.inf)
    return seg, np.concatenate(found)


def _options(tel, bundle, n_grid):
    """A function of the skirt radius r_s: every (r_s, skirt bottom, tube radius, tube top, slack, field
    stop) whose skirt and tube clear the beams that r_s's cap lets through (slack < 0: the direct-path
    condition (3) fails by that much), one per tube height; and the tube's bottom."""
    R = tel.aperture_radius_mm
    margin = margin_mm(R)
    u_top = tel.secondary_rim_u
    u_i = tel.image_u
    h = tel.image_radius_mm
    tube_bottom = u_i + 1e-3 * max(R, 1.0)
    us = np.linspace(min(tel.primary_hole_u, u_i), u_top, n_grid)
    up = np.linspace(max(tel.primary_hole_u, u_i) - 0.0, u_top, n_grid)
    inner = _Suffix(*_fam(bundle, ("ps", "si")), us[:, None], u_top, "max")
    need = _Suffix(*_fam(bundle, ("si",)), tube_bottom, up[:, None], "max")
    room = _Suffix(*_fam(bundle, ("in", "ps")), tube_bottom, up[:, None], "min")
    # the field stop: the beam of the field where it leaves the tube's bottom, just above the image
    field = _Suffix(*_fam(bundle, ("si",)), np.array([[u_i]]), np.array([[tube_bottom]]), "max")

    def options(r):
        kept = r - margin  # rays crossing the cap's plane inside this are stopped by the cap (with margin)
        # skirt: the lowest bottom that keeps the inner beams inside
        m_inner = np.nan_to_num(inner.at(kept), nan=0.0)
        ok = np.flatnonzero(m_inner < r - margin)
        usk = us[ok[0]] if len(ok) else u_top
        # tube: for each top height, the least radius clearing the converging beam, and its room
        a_need = np.nan_to_num(need.at(kept), nan=0.0) + margin
        a_room = np.nan_to_num(room.at(kept), nan=math.inf) - margin
        b = float(np.nan_to_num(field.at(kept), nan=0.0)[0]) + margin
        out = []
        for j, u in enumerate(up):
            a = a_need[j]
            if a > a_room[j] or u >= usk - margin:
                continue
            stop = b if b < min(a, h) - margin else None
            slack = r - margin - max_exit(apertures(tel, tube_bottom, a, u, stop), usk)
            out.append((r, usk, a, u, slack, stop))
        return out

    return options, tube_bottom


def apertures(tel, tube_bottom, a, u_top, stop) -> list[tuple[float, float]]:
    """The (height, radius) apertures a line from the image up the tube passes: the detector disk, the
    tube's bottom (or the field stop there), the tube's rim."""
    return [(tel.image_u, tel.image_radius_mm), (tube_bottom, a if stop is None else stop), (u_top, a)]


def _scan(tel, bundle, max_added, n_grid, n_radii, radius_step) -> list[Layout]:
    """Feasible layouts by increasing skirt radius (two tube choices per radius), up to ``n_radii`` radii
    at least ``radius_step`` x the aperture radius apart, stopping past the obscuration budget. For each
    skirt radius only the rays its cap lets through constrain the skirt and the tube (:class:`_Suffix`)."""
    R = tel.aperture_radius_mm
    margin = margin_mm(R)
    options, tube_bottom = _options(tel, bundle, n_grid)
    r_grid = np.linspace(tel.secondary_outer_mm, R, n_grid)
    before = obscuration(tel, bundle, None)

    def feasible_at(r):
        return [c for c in options(r) if c[4] >= 0]

    out = []
    last_r, radii = None, 0
    for k, r in enumerate(r_grid):
        if last_r is not None and r < last_r + radius_step * R:
            continue
        feasible = feasible_at(r)
        if feasible and radii == 0 and k > 0:  # the smallest skirt: bisect between the grid's radii
            lo, hi = float(r_grid[k - 1]), float(r)
            for _ in range(8):
                mid = 0.5 * (lo + hi)
                f_mid = feasible_at(mid)
                if f_mid:
                    hi, feasible = mid, f_mid
                else:
                    lo = mid
        if not feasible:
            continue
        picks = [max(feasible, key=lambda c: c[4])]  # the construction: the largest margin
        if len(feasible) > 1:
            picks.append(min(feasible, key=lambda c: c[3]))  # the shortest tube
        for cand in picks:
            lay = _layout(tel, cand, tube_bottom, margin)
            lay.obscuration_before = before
            lay.obscuration_after = obscuration(tel, bundle, lay)
            out.append(lay)
        last_r, radii = r, radii + 1
        if radii >= n_radii or lay.obscuration_after - before > max_added:
            break
    return out


def within_budget(tel, bundle, max_added: float, n_grid: int = 240) -> Layout | None:
    """The widest skirt whose layout adds at most ``max_added`` obscuration, with the tube that leaves the
    least of the direct view open (largest slack, negative: condition (3) fails); None when even the
    narrowest skirt does not fit. For a sunshade to close what the skirt leaves open."""
    R = tel.aperture_radius_mm
    margin = margin_mm(R)
    options, tube_bottom = _options(tel, bundle, n_grid)
    before = obscuration(tel, bundle, None)

    def best(r):
        opts = options(r)
        if not opts:
            return None
        lay = _layout(tel, max(opts, key=lambda c: c[4]), tube_bottom, margin)
        lay.obscuration_before = before
        lay.obscuration_after = obscuration(tel, bundle, lay)
        return lay if lay.obscuration_after - before <= max_added else None

    good, lo, hi = None, None, None
    for r in np.linspace(tel.secondary_outer_mm, R, n_grid):
        lay = best(float(r))
        if lay is None and good is not None:
            hi = float(r)
            break
        if lay is not None:
            good, lo = lay, float(r)
    if good is None or lo is None:
        return None
    if hi is not None:  # bisect the budget's edge between the grid's radii
        for _ in range(8):
            mid = 0.5 * (lo + hi)
            lay = best(mid)
            if lay is not None:
                good, lo = lay, mid
            else:
                hi = mid
    return good


def construct(tel, bundle, max_added: float = 0.05, n_grid: int = 240) -> Layout:
    """The least-obscuring layout (module docstring); raises NoShieldError when none fits ``max_added``."""
    return candidates(tel, bundle, max_added, n_grid)[0]


def candidates(tel, bundle, max_added: float = 0.05, n_grid: int = 240, n_radii: int = 1,
               radius_step: float = 0.0) -> list[Layout]:
    """Layouts that close every direct path within ``max_added``: the construction first (smallest skirt,
    largest margin), then, for the refinement, the shortest tube with that skirt and both choices for
    ``n_radii - 1`` wider skirts (each ``radius_step`` of the aperture radius wider). Raises NoShieldError
    when none fits."""
    lays = _scan(tel, bundle, max_added, n_grid, n_radii, radius_step)
    before = lays[0].obscuration_before if lays else 0.0
    fits = [x for x in lays if x.obscuration_after - x.obscuration_before <= max_added + 1e-12]
    if fits:
        return fits
    if lays:
        exc = NoShieldError(
            f"no shield blocks every direct path within the allowed obscuration: the smallest that does "
            f"adds {lays[0].obscuration_after - before:.4f} of the aperture area "
            f"(--max-added-obscuration {max_added:g})")
        exc.smallest_added = lays[0].obscuration_after - before
        raise exc
    raise NoShieldError("no shield blocks every direct path within the allowed obscuration: no skirt up to "
                        f"the aperture radius ({tel.aperture_radius_mm:.4g} mm) closes the view from the image to "
                        f"the sky (--max-added-obscuration {max_added:g})")


def _layout(tel, cand, tube_bottom, margin) -> Layout:
    r, usk, a, u, slack, stop = cand
    rear_from = min(tel.image_u, tel.primary_rim_u) - 2 * margin
    return Layout(skirt_radius_mm=float(r), skirt_bottom_u=float(usk), tube_radius_mm=float(a),
                  tube_top_u=float(u), tube_bottom_u=float(tube_bottom), cap_u=float(tel.secondary_rim_u),
                  collar=bool(a < tel.primary_hole_mm), rear_radius_mm=float(tel.primary_outer_mm + margin),
                  rear_from_u=float(rear_from), rear_to_u=float(tel.primary_rim_u), direct_margin_mm=float(slack),
                  field_stop_radius_mm=None if stop is None else float(stop))


def baffle_parts(tel, lay: Layout, material: str = "z302_sample_b") -> list[dict]:
    """The layout as scene parts (CONTRACTS 6.1 analytic surfaces) and as design.json entries."""
    ax = [float(v) for v in tel.axis]

    def vec(p):
        return [float(v) for v in p]

    out = []
    out.append({"name": "baffle_secondary", "type": "secondary_skirt", "shape": "cylinder",
                "radius_mm": lay.skirt_radius_mm, "length_mm": lay.cap_u - lay.skirt_bottom_u,
                "from_mm": vec(tel.point(lay.skirt_bottom_u)), "to_mm": vec(tel.point(lay.cap_u)),
                "surface": {"type": "cylinder", "vertex_mm": vec(tel.point(lay.skirt_bottom_u)), "axis": ax,
                            "radius_mm": lay.skirt_radius_mm, "length_mm": lay.cap_u - lay.skirt_bottom_u}})
    if lay.skirt_radius_mm > tel.secondary_outer_mm + 1e-9:
        # a spot on a corrector: the glass around it meets the cap's plane at the rim, and a ray leaving the
        # glass there starts within the tracer's self-intersection offset of the cap and would skip it; the
        # cap sits a quarter of the clearance lower and overlaps the spot's and the skirt's edges by a quarter
        # of that (closed for lines within 14 deg of the axis; the lines up the tube are steeper than 6 deg only
        # in telescopes far faster than f/4)
        seam = 0.25 * margin_mm(tel.aperture_radius_mm) if tel.extra.get("secondary_on_glass") else 0.0
        cap_u, r_in, r_out = lay.cap_u - seam, tel.secondary_outer_mm - 0.25 * seam, lay.skirt_radius_mm + 0.25 * seam
        out.append({"name": "baffle_secondary_cap", "type": "secondary_cap", "shape": "annulus",
                    "inner_radius_mm": r_in, "outer_radius_mm": r_out, "center_mm": vec(tel.point(cap_u)),
                    "surface": {"type": "plane", "vertex_mm": vec(tel.point(cap_u)), "axis": ax,
                                "outer_radius_mm": r_out, "inner_radius_mm": r_in}})
    out.append({"name": "baffle_primary", "type": "primary_tube", "shape": "cylinder",
                "radius_mm": lay.tube_radius_mm, "length_mm": lay.tube_top_u - lay.tube_bottom_u,
                "from_mm": vec(tel.point(lay.tube_bottom_u)), "to_mm": vec(tel.point(lay.tube_top_u)),
                "surface": {"type": "cylinder", "vertex_mm": vec(tel.point(lay.tube_bottom_u)), "axis": ax,
                            "radius_mm": lay.tube_radius_mm, "length_mm": lay.tube_top_u - lay.tube_bottom_u}})
    if lay.field_stop_radius_mm is not None:
        outer = lay.tube_radius_mm + margin_mm(tel.aperture_radius_mm)  # overlaps the tube's wall: no gap
        out.append({"name": "baffle_field_stop", "type": "field_stop", "shape": "annulus",
                    "inner_radius_mm": lay.field_stop_radius_mm, "outer_radius_mm": outer,
                    "center_mm": vec(tel.point(lay.tube_bottom_u)),
                    "surface": {"type": "plane", "vertex_mm": vec(tel.point(lay.tube_bottom_u)), "axis": ax,
                                "outer_radius_mm": outer, "inner_radius_mm": lay.field_stop_radius_mm}})
    if lay.collar:
        uc = tel.primary_hole_u - 1e-3
        outer = tel.primary_hole_mm + max(1e-3 * tel.aperture_radius_mm, 0.01)
        out.append({"name": "baffle_primary_collar", "type": "primary_collar", "shape": "annulus",
                    "inner_radius_mm": lay.tube_radius_mm, "outer_radius_mm": outer, "center_mm": vec(tel.point(uc)),
                    "surface": {"type": "plane", "vertex_mm": vec(tel.point(uc)), "axis": ax,
                                "outer_radius_mm": outer, "inner_radius_mm": lay.tube_radius_mm}})
    sh = lay.sunshade
    if sh is not None:
        length = sh.to_u - sh.from_u
        out.append({"name": "baffle_sunshade", "type": "sunshade", "shape": "cylinder",
                    "radius_mm": sh.radius_mm, "length_mm": length,
                    "from_mm": vec(tel.point(sh.from_u)), "to_mm": vec(tel.point(sh.to_u)),
                    "surface": {"type": "cylinder", "vertex_mm": vec(tel.point(sh.from_u)), "axis": ax,
                                "radius_mm": sh.radius_mm, "length_mm": length}})
    if lay.rear_to_u > lay.rear_from_u:
        out.append({"name": "baffle_rear", "type": "rear_enclosure", "shape": "cylinder",
                    "radius_mm": lay.rear_radius_mm, "length_mm": lay.rear_to_u - lay.rear_from_u,
                    "from_mm": vec(tel.point(lay.rear_from_u)), "to_mm": vec(tel.point(lay.rear_to_u)),
                    "surface": {"type": "cylinder", "vertex_mm": vec(tel.point(lay.rear_from_u)), "axis": ax,
                                "radius_mm": lay.rear_radius_mm, "length_mm": lay.rear_to_u - lay.rear_from_u}})
    for p in out:
        p["material"] = material
    return out
