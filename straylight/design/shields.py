"""Exact construction of a two-mirror telescope's light shields from the edge rays of the field.

The classical layout (Young, Appl. Opt. 6, 1063 (1967); Breault, Handbook of Optics vol. II ch. 38):

- ``baffle_secondary``: a skirt (cylinder of radius r_s) hanging from the secondary's rim toward the
  primary down to u_s, closed at the top by ``baffle_secondary_cap`` (the annulus between the
  mirror's rim and the skirt);
- ``baffle_primary``: a tube of radius a about the axis, from the image plane up to u_p (through the
  primary's hole; ``baffle_primary_collar`` closes the hole around it when a is smaller);
- ``baffle_rear``: a cylinder at the primary's rim down past the image plane, so the detector sees
  the sky only through the tube.

Constraints, all exact in the meridional plane (u along the axis, y across it), for the nominal
rays of every field angle in [-F, F] (:func:`straylight.design.telescope_model.nominal_bundle`):

1. the tube must not touch the converging beam (secondary to image): a > max |y| of that beam over
   the tube's height, and it must not touch the rays going to or from the primary;
2. the skirt must not touch the beam primary -> secondary or secondary -> image: r_s > their max |y|
   over [u_s, rim]; so a wider skirt may hang lower;
3. no direct path: the steepest line from the detector's edge (-h, u_i) through the tube's rim
   (a, u_p) must enter the skirt's mouth: y(u_s) = -h + (a + h)(u_s - u_i)/(u_p - u_i) <= r_s
   (in 3-D the meridional line is the worst: the distance from the axis of a point (1-t)p + tq is at
   most (t-1)|p| + t|q| for t > 1, with equality for p, q opposite).

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
    """No layout blocks every direct path within the allowed obscuration (one-line message)."""


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


def _nanmax(x, default=0.0):
    x = x[np.isfinite(x)]
    return float(x.max()) if len(x) else default


def _nanmin(x, default=math.inf):
    x = x[np.isfinite(x)]
    return float(x.min()) if len(x) else default


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


def _scan(tel, bundle, max_added, n_grid, n_radii, radius_step) -> list[Layout]:
    """Feasible layouts by increasing skirt radius (two tube choices per radius), up to ``n_radii`` radii
    at least ``radius_step`` x the aperture radius apart, stopping past the obscuration budget. For each
    skirt radius only the rays its cap lets through constrain the skirt and the tube (:class:`_Suffix`)."""
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
    r_grid = np.linspace(tel.secondary_outer_mm, R, n_grid)
    before = obscuration(tel, bundle, None)
    out = []
    last_r, radii = None, 0
    for k, r in enumerate(r_grid):
        if last_r is not None and r < last_r + radius_step * R:
            continue
        kept = r - margin  # rays crossing the cap's plane inside this are stopped by the cap (with margin)
        # skirt: the lowest bottom that keeps the inner beams inside
        m_inner = np.nan_to_num(inner.at(kept), nan=0.0)
        ok = np.flatnonzero(m_inner < r - margin)
        usk = us[ok[0]] if len(ok) else u_top
        # tube: for each top height, the least radius clearing the converging beam, and its room
        a_need = np.nan_to_num(need.at(kept), nan=0.0) + margin
        a_room = np.nan_to_num(room.at(kept), nan=math.inf) - margin
        feasible = []
        for j, u in enumerate(up):
            a = a_need[j]
            if a > a_room[j] or u >= usk - margin:
                continue
            he = min(h, a)
            x = -he + (a + he) * (usk - u_i) / (u - u_i)
            slack = r - margin - x
            if slack >= 0:
                feasible.append((r, usk, a, u, slack))
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
        raise NoShieldError(
            f"no shield blocks every direct path within the allowed obscuration: the smallest that does "
            f"adds {lays[0].obscuration_after - before:.4f} of the aperture area "
            f"(--max-added-obscuration {max_added:g})")
    raise NoShieldError("no shield blocks every direct path within the allowed obscuration: no skirt up to "
                        f"the aperture radius ({tel.aperture_radius_mm:.4g} mm) closes the view from the image to "
                        f"the sky (--max-added-obscuration {max_added:g})")


def _layout(tel, cand, tube_bottom, margin) -> Layout:
    r, usk, a, u, slack = cand
    rear_from = min(tel.image_u, tel.primary_rim_u) - 2 * margin
    return Layout(skirt_radius_mm=float(r), skirt_bottom_u=float(usk), tube_radius_mm=float(a),
                  tube_top_u=float(u), tube_bottom_u=float(tube_bottom), cap_u=float(tel.secondary_rim_u),
                  collar=bool(a < tel.primary_hole_mm), rear_radius_mm=float(tel.primary_outer_mm + margin),
                  rear_from_u=float(rear_from), rear_to_u=float(tel.primary_rim_u), direct_margin_mm=float(slack))


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
        out.append({"name": "baffle_secondary_cap", "type": "secondary_cap", "shape": "annulus",
                    "inner_radius_mm": tel.secondary_outer_mm, "outer_radius_mm": lay.skirt_radius_mm,
                    "center_mm": vec(tel.point(lay.cap_u)),
                    "surface": {"type": "plane", "vertex_mm": vec(tel.point(lay.cap_u)), "axis": ax,
                                "outer_radius_mm": lay.skirt_radius_mm, "inner_radius_mm": tel.secondary_outer_mm}})
    out.append({"name": "baffle_primary", "type": "primary_tube", "shape": "cylinder",
                "radius_mm": lay.tube_radius_mm, "length_mm": lay.tube_top_u - lay.tube_bottom_u,
                "from_mm": vec(tel.point(lay.tube_bottom_u)), "to_mm": vec(tel.point(lay.tube_top_u)),
                "surface": {"type": "cylinder", "vertex_mm": vec(tel.point(lay.tube_bottom_u)), "axis": ax,
                            "radius_mm": lay.tube_radius_mm, "length_mm": lay.tube_top_u - lay.tube_bottom_u}})
    if lay.collar:
        uc = tel.primary_hole_u - 1e-3
        outer = tel.primary_hole_mm + max(1e-3 * tel.aperture_radius_mm, 0.01)
        out.append({"name": "baffle_primary_collar", "type": "primary_collar", "shape": "annulus",
                    "inner_radius_mm": lay.tube_radius_mm, "outer_radius_mm": outer, "center_mm": vec(tel.point(uc)),
                    "surface": {"type": "plane", "vertex_mm": vec(tel.point(uc)), "axis": ax,
                                "outer_radius_mm": outer, "inner_radius_mm": lay.tube_radius_mm}})
    if lay.rear_to_u > lay.rear_from_u:
        out.append({"name": "baffle_rear", "type": "rear_enclosure", "shape": "cylinder",
                    "radius_mm": lay.rear_radius_mm, "length_mm": lay.rear_to_u - lay.rear_from_u,
                    "from_mm": vec(tel.point(lay.rear_from_u)), "to_mm": vec(tel.point(lay.rear_to_u)),
                    "surface": {"type": "cylinder", "vertex_mm": vec(tel.point(lay.rear_from_u)), "axis": ax,
                                "radius_mm": lay.rear_radius_mm, "length_mm": lay.rear_to_u - lay.rear_from_u}})
    for p in out:
        p["material"] = material
    return out
