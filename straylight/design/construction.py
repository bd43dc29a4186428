"""The classic vane construction of a cylindrical baffle tube, in exact meridional geometry.

Frame (CONTRACTS 4.6): tube axis z; wall r = R, 0 <= z <= L; entrance = the open end z = L;
detector (or aperture stop) = the disk r <= S at z = 0 facing +z. Vane k is the annulus
r_k..R, thickness t, centred at z_k. Its inner edge is a straight profile between two *corners*,
(z_k + t/2, r_top) and (z_k - t/2, r_bot); a bevel of angle b widens one face's hole by
t tan b (knife edge on the other face). The entrance is one more corner, (L, R).

Everything below is closed-form geometry of straight lines and corners (docs/design.md):

- field envelope: a ray within the field (off-axis angle <= F) that reaches the detector disk
  is at radius <= S + z tan F at height z, so a vane whose corners all satisfy
  r_c >= S + z_c tan F vignettes nothing; the vanes' inner edges are put on that envelope.
- lit (Freniere 1980): a wall point (R, z_w) is lit at off-axis angle theta iff for every corner
  c above it z_c - (R + r_c)/tan(theta) < z_w < z_c - (R - r_c)/tan(theta). Over theta >= E the
  lit part of a bay is [lo(E), hi(theta*)], with tan(theta*) = min over corner pairs
  (r_c + r_c') / (z_c - z_c'): beyond theta* no ray passes both corners.
- seen: the wall point is seen from the detector iff, for every corner c below it,
  z_w > z_c (R + S) / (r_c + S) (the far detector edge (-S, 0) sees most).

Both statements are exact in 3-D for coaxial circular apertures: the meridional plane holds the
best ray for both (tilt azimuth toward the wall point; the detector point opposite it), and the
radius along a straight ray is convex in z, so corners suffice for a piecewise-straight edge.

The construction works from the entrance down (Freniere 1980; Breault 1977): the top vane is the
lowest one over which the detector sees no wall; each next vane is the lowest one whose view
line from the far detector edge meets the wall at or above the highest point of the bay above
that light at theta >= E can reach, so no wall section is both lit and seen. It stops when no
light at E or beyond gets past the last vane.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

BEVEL_SIDES = ("back", "front")
GAP_MM = 1e-6  # smallest gap left between neighbouring vanes by the construction


class DesignError(ValueError):
    """A design request that cannot be met; the message names the parameter."""


@dataclass(frozen=True)
class BaffleSpec:
    """A tube and what its vanes must do (lengths mm, angles deg).

    tube_radius_mm R, tube_length_mm L, stop_radius_mm S : the frame above
    field_deg F : nothing within F off axis may touch a vane on its way to the detector
    exclusion_deg E : light at E and beyond must not light a wall section the detector sees
    vane_thickness_mm t, bevel_deg, bevel_side : vane profile ("back": the bevel faces the
        detector, knife edge on the entrance side, as geometry.parts.tube.vane)
    max_vanes : the construction stops there (and reports what is still lit and seen)
    keep_out_mm : ((z_lo, z_hi), ...) intervals where no vane may be (an obstruction, a mount)
    """

    tube_radius_mm: float
    tube_length_mm: float
    stop_radius_mm: float
    field_deg: float
    exclusion_deg: float
    vane_thickness_mm: float = 1.0
    bevel_deg: float = 0.0
    bevel_side: str = "back"
    max_vanes: int = 30
    keep_out_mm: tuple = ()

    def __post_init__(self):
        object.__setattr__(self, "keep_out_mm",
                           tuple((float(a), float(b)) for a, b in (self.keep_out_mm or ())))
        self.validate()

    def validate(self):
        """Raise DesignError (one line) naming the first bad parameter."""
        for name in ("tube_radius_mm", "tube_length_mm", "stop_radius_mm", "vane_thickness_mm"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise DesignError(f"{name} must be a finite number > 0, got {value!r}")
        R, L, S, t = self.tube_radius_mm, self.tube_length_mm, self.stop_radius_mm, self.vane_thickness_mm
        if not S < R:
            raise DesignError(f"stop_radius_mm ({S:g}) must be below tube_radius_mm ({R:g})")
        if not (math.isfinite(self.field_deg) and 0 <= self.field_deg < 90):
            raise DesignError(f"field_deg must be in [0, 90), got {self.field_deg!r}")
        if not (math.isfinite(self.exclusion_deg) and 0 < self.exclusion_deg < 90):
            raise DesignError(f"exclusion_deg must be in (0, 90), got {self.exclusion_deg!r}")
        if not self.field_deg < self.exclusion_deg:
            raise DesignError(f"field_deg ({self.field_deg:g}) must be below exclusion_deg ({self.exclusion_deg:g})")
        top = S + L * math.tan(math.radians(self.field_deg))
        if not top < R:
            raise DesignError(f"field_deg ({self.field_deg:g}) too wide for the tube: the field envelope "
                              f"S + L tan F = {top:.4g} mm at the entrance is not below tube_radius_mm ({R:g})")
        if not t < L / 2:
            raise DesignError(f"vane_thickness_mm ({t:g}) must be below half the tube length ({L / 2:g})")
        if not (math.isfinite(self.bevel_deg) and 0 <= self.bevel_deg < 90):
            raise DesignError(f"bevel_deg must be in [0, 90), got {self.bevel_deg!r}")
        if self.bevel_side not in BEVEL_SIDES:
            raise DesignError(f"bevel_side must be one of {', '.join(BEVEL_SIDES)}, got {self.bevel_side!r}")
        if isinstance(self.max_vanes, bool) or int(self.max_vanes) != self.max_vanes or self.max_vanes < 1:
            raise DesignError(f"max_vanes must be an integer >= 1, got {self.max_vanes!r}")
        for lo, hi in self.keep_out_mm:
            if not (math.isfinite(lo) and math.isfinite(hi) and 0 <= lo < hi <= L):
                raise DesignError(f"keep-out zone ({lo:g}, {hi:g}) mm must satisfy 0 <= z_lo < z_hi <= "
                                  f"tube_length_mm ({L:g})")

    @property
    def tan_field(self) -> float:
        return math.tan(math.radians(self.field_deg))

    @property
    def tan_exclusion(self) -> float:
        return math.tan(math.radians(self.exclusion_deg))

    @property
    def bevel_run_mm(self) -> float:
        """How much wider the bevelled face's hole is than the knife edge: t tan(bevel)."""
        return self.vane_thickness_mm * math.tan(math.radians(self.bevel_deg))

    def envelope_radius_mm(self, z_mm: float) -> float:
        """Field envelope S + z tan F: the largest radius of a field ray that reaches the detector."""
        return self.stop_radius_mm + z_mm * self.tan_field

    def vane_at(self, z_mm: float) -> "Vane":
        """The vane centred at ``z_mm`` whose inner edge touches the field envelope."""
        half, run = self.vane_thickness_mm / 2, self.bevel_run_mm
        # knife edge at the top for "back", at the bottom for "front"; the other face is wider by run
        if self.bevel_side == "back":
            r = max(self.envelope_radius_mm(z_mm + half), self.envelope_radius_mm(z_mm - half) - run)
        else:
            r = max(self.envelope_radius_mm(z_mm - half), self.envelope_radius_mm(z_mm + half) - run)
        return Vane(float(z_mm), float(r), float(self.vane_thickness_mm))

    def corners(self, vane: "Vane") -> tuple[tuple[float, float], tuple[float, float]]:
        """((z_top, r_top), (z_bottom, r_bottom)) of a vane's inner edge."""
        half, run = vane.thickness_mm / 2, vane.thickness_mm * math.tan(math.radians(self.bevel_deg))
        top, bottom = vane.inner_radius_mm, vane.inner_radius_mm
        if self.bevel_side == "back":
            bottom += run
        else:
            top += run
        return (vane.z_mm + half, top), (vane.z_mm - half, bottom)


@dataclass(frozen=True)
class Vane:
    """The annulus inner_radius_mm..R of thickness thickness_mm centred at z_mm (CONTRACTS 4.6)."""

    z_mm: float
    inner_radius_mm: float
    thickness_mm: float

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class Bay:
    """The wall between two vanes (or a vane and the end plate / entrance), with what is lit and seen.

    z_lo_mm, z_hi_mm : the wall section; lit_mm / seen_mm / lit_and_seen_mm : (z_lo, z_hi) or None
    lit_until_deg : theta*, the largest off-axis angle whose light reaches this bay (None: unlit at E)
    """

    z_lo_mm: float
    z_hi_mm: float
    lit_mm: tuple | None
    seen_mm: tuple | None
    lit_and_seen_mm: tuple | None
    lit_until_deg: float | None

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class Layout:
    """A vane layout and its exact meridional analysis.

    vanes : sorted by z; bays : from the end plate up to the entrance
    vignetting_margin_mm : min over vane corners of r_c - envelope(z_c) (>= 0: nothing in the field vignettes)
    complete : no wall section is both lit at >= E and seen from the detector
    notes : what the construction had to give up (max count, keep-out), one line each
    """

    spec: BaffleSpec
    vanes: tuple
    bays: tuple
    vignetting_margin_mm: float
    notes: tuple = field(default_factory=tuple)

    @property
    def complete(self) -> bool:
        return all(b.lit_and_seen_mm is None for b in self.bays)

    @property
    def lit_and_seen_mm(self) -> float:
        """Total wall length (meridional) both lit at >= E and seen from the detector."""
        return sum(b.lit_and_seen_mm[1] - b.lit_and_seen_mm[0] for b in self.bays if b.lit_and_seen_mm)

    def to_dict(self) -> dict:
        return {"spec": {k: (list(map(list, v)) if k == "keep_out_mm" else v) for k, v in asdict(self.spec).items()},
                "vanes": [v.to_dict() for v in self.vanes], "bays": [b.to_dict() for b in self.bays],
                "vignetting_margin_mm": self.vignetting_margin_mm, "complete": self.complete,
                "lit_and_seen_mm": self.lit_and_seen_mm, "notes": list(self.notes)}


def _interval(lo: float, hi: float):
    return (float(lo), float(hi)) if hi > lo else None


def lit_interval(spec: BaffleSpec, corners_above, z_lo: float, z_hi: float):
    """(lit (z_lo, z_hi) or None, theta* in deg or None): wall in [z_lo, z_hi] lit at off-axis >= E.

    corners_above : (z_c, r_c) of every aperture corner above the section (entrance included).
    """
    R, tan_e = spec.tube_radius_mm, spec.tan_exclusion
    cs = sorted(corners_above, reverse=True)
    tan_star = math.inf  # pairs of corners: beyond theta* no ray passes both
    for i, (za, ra) in enumerate(cs):
        for zb, rb in cs[i + 1:]:
            if za > zb:
                tan_star = min(tan_star, (ra + rb) / (za - zb))
    if tan_star <= tan_e:
        return None, None
    lo = max(zc - (R + rc) / tan_e for zc, rc in cs)
    hi = min(zc - (R - rc) / tan_star for zc, rc in cs) if math.isfinite(tan_star) else min(zc for zc, _ in cs)
    theta_star = math.degrees(math.atan(tan_star)) if math.isfinite(tan_star) else 90.0
    return _interval(max(lo, z_lo), min(hi, z_hi)), theta_star


def seen_interval(spec: BaffleSpec, corners_below, z_lo: float, z_hi: float):
    """Wall in [z_lo, z_hi] seen from some point of the detector disk, (z_lo, z_hi) or None."""
    R, S = spec.tube_radius_mm, spec.stop_radius_mm
    start = max([z_lo] + [zc * (R + S) / (rc + S) for zc, rc in corners_below])
    return _interval(start, z_hi)


def analyse_layout(spec: BaffleSpec, vanes, notes=()) -> Layout:
    """Exact lit / seen wall sections of every bay and the vignetting margin of a vane list."""
    vanes = tuple(sorted(vanes, key=lambda v: v.z_mm))
    L = spec.tube_length_mm
    corners = [spec.corners(v) for v in vanes]
    for (top, bottom), v in zip(corners, vanes):
        if bottom[0] <= 0 or top[0] >= L:
            raise DesignError(f"vane at z = {v.z_mm:g} mm sticks out of the tube (0 < z +- t/2 < {L:g})")
        if max(top[1], bottom[1]) >= spec.tube_radius_mm:
            raise DesignError(f"vane at z = {v.z_mm:g} mm has no depth: inner radius "
                              f"{v.inner_radius_mm:g} mm is not below tube_radius_mm")
    for (c1, c2) in zip(corners, corners[1:]):
        if c2[1][0] <= c1[0][0]:
            raise DesignError(f"vanes overlap near z = {c1[0][0]:g} mm")
    edges = [0.0] + [z for c in corners for z in (c[1][0], c[0][0])] + [L]
    flat = [c for pair in corners for c in pair]
    bays = []
    for k in range(len(vanes) + 1):
        z_lo, z_hi = edges[2 * k], edges[2 * k + 1]
        above = [c for c in flat if c[0] >= z_hi] + [(L, spec.tube_radius_mm)]
        below = [c for c in flat if c[0] <= z_lo]
        lit, theta_star = lit_interval(spec, above, z_lo, z_hi)
        seen = seen_interval(spec, below, z_lo, z_hi)
        both = _interval(max(lit[0], seen[0]), min(lit[1], seen[1])) if lit and seen else None
        bays.append(Bay(z_lo, z_hi, lit, seen, both, theta_star if lit else None))
    margin = min((r - spec.envelope_radius_mm(z) for z, r in flat), default=math.inf)
    return Layout(spec, vanes, tuple(bays), float(margin), tuple(notes))


def _seen_from(spec: BaffleSpec, z_mm: float) -> float:
    """Lowest wall height the detector sees over the vane centred at z_mm (its corners only)."""
    R, S = spec.tube_radius_mm, spec.stop_radius_mm
    return max(zc * (R + S) / (rc + S) for zc, rc in spec.corners(spec.vane_at(z_mm)))


def _lowest_vane_hiding(spec: BaffleSpec, target_mm: float, z_min: float, z_max: float) -> float:
    """Lowest centre z in [z_min, z_max] whose vane hides the wall below ``target_mm`` (bisection;
    the hidden height rises with z). Returns z_max if even that does not reach."""
    if _seen_from(spec, z_min) >= target_mm:
        return z_min
    if _seen_from(spec, z_max) < target_mm:
        return z_max
    lo, hi = z_min, z_max
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if _seen_from(spec, mid) >= target_mm:
            hi = mid
        else:
            lo = mid
        if hi - lo < 1e-10 * max(1.0, spec.tube_length_mm):
            break
    return hi


def _out_of_keep_out(spec: BaffleSpec, z_mm: float, z_max: float) -> tuple[float, str | None]:
    """Move a vane centre up out of the keep-out zones (higher hides more); (z, note or None)."""
    half = spec.vane_thickness_mm / 2
    moved = True
    z = z_mm
    while moved:
        moved = False
        for lo, hi in spec.keep_out_mm:
            if z + half > lo and z - half < hi:
                z, moved = hi + half + GAP_MM, True
    if z <= z_max:
        return z, None
    # no room above: put it just below the zone instead, and say so
    z = z_mm
    for lo, hi in sorted(spec.keep_out_mm, reverse=True):
        if z + half > lo and z - half < hi:
            z = lo - half - GAP_MM
    return z, (f"keep-out zone pushed the vane at z = {z:.4g} mm below where the construction wanted it "
               f"({z_mm:.4g} mm): part of the bay above it is both lit and seen")


def construct_vanes(tube_radius_mm: float, tube_length_mm: float, stop_radius_mm: float, field_deg: float,
                    exclusion_deg: float, *, vane_thickness_mm: float = 1.0, bevel_deg: float = 0.0,
                    bevel_side: str = "back", max_vanes: int = 30, keep_out_mm=()) -> Layout:
    """Freniere's vane construction for a tube (CONTRACTS 4.6 frame); returns the :class:`Layout`:
    the vanes (z, inner radius on the field envelope, thickness) and the lit / seen wall of every bay.

    Raises DesignError (one line) for impossible inputs (S >= R, F >= E, field wider than the tube...).
    """
    spec = BaffleSpec(float(tube_radius_mm), float(tube_length_mm), float(stop_radius_mm), float(field_deg),
                      float(exclusion_deg), float(vane_thickness_mm), float(bevel_deg), bevel_side, max_vanes,
                      tuple(keep_out_mm or ()))
    return construct(spec)


def construct(spec: BaffleSpec) -> Layout:
    """:func:`construct_vanes` for a :class:`BaffleSpec`."""
    L, half = spec.tube_length_mm, spec.vane_thickness_mm / 2
    corners_above = [(L, spec.tube_radius_mm)]
    ceiling = L  # lowest corner placed so far: the top of the bay being closed
    vanes: list = []
    notes: list[str] = []
    while True:
        lit, _ = lit_interval(spec, corners_above, 0.0, ceiling)
        if lit is None:
            break  # no light at >= E gets below the last vane
        z_max = ceiling - half - GAP_MM
        if z_max < half + GAP_MM:
            notes.append(f"no room for a vane below z = {ceiling:.4g} mm: the wall there is lit at "
                         f"{spec.exclusion_deg:g} deg and seen")
            break
        if len(vanes) == spec.max_vanes:
            notes.append(f"stopped at max_vanes = {spec.max_vanes}: light at {spec.exclusion_deg:g} deg still "
                         f"reaches the wall below z = {ceiling:.4g} mm")
            break
        # the bay above the new vane is lit up to lit[1]; hide everything below that from the detector
        z = _lowest_vane_hiding(spec, lit[1], half + GAP_MM, z_max)
        if spec.keep_out_mm:
            z, note = _out_of_keep_out(spec, z, z_max)
            if note:
                notes.append(note)
            if z < half + GAP_MM:
                notes.append("keep-out zone leaves no room for the lowest vane")
                break
        vane = spec.vane_at(z)
        if vane.inner_radius_mm + spec.bevel_run_mm >= spec.tube_radius_mm:
            raise DesignError(f"vane at z = {z:.4g} mm has no depth: bevel_deg ({spec.bevel_deg:g}) runs "
                              f"{spec.bevel_run_mm:.3g} mm, deeper than R - envelope")
        vanes.append(vane)
        top, bottom = spec.corners(vane)
        corners_above += [top, bottom]
        ceiling = bottom[0]
    return analyse_layout(spec, vanes, notes)


def evenly_spaced(spec: BaffleSpec, count: int) -> Layout:
    """The baseline: ``count`` vanes at z_k = k L / (count + 1), inner edges on the same field envelope."""
    L = spec.tube_length_mm
    return analyse_layout(spec, [spec.vane_at(k * L / (count + 1)) for k in range(1, count + 1)])


def layout_at(spec: BaffleSpec, z_mm) -> Layout:
    """Vanes centred at ``z_mm`` with inner edges on the field envelope, analysed."""
    return analyse_layout(spec, [spec.vane_at(float(z)) for z in z_mm])
