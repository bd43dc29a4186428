"""Baffled telescope tube: wall, vanes, end plate (field stop), optional aperture stop, detector.

The z axis is the tube axis; light enters at z = ``length_mm`` and travels toward -z.
All parts are separate solids that touch (vanes and end plate touch the wall; nothing
overlaps), so path reports can name them: "wall", "vane_1" (lowest z) .. "vane_N",
"end_plate", "aperture_stop" (if any), "detector". Where two parts touch, their
common faces are hidden from every ray that starts inside the tube, so a tracer
sees the same surfaces as it would on the fused solid (``fuse_solids`` gives that
single solid when one is wanted, e.g. for export to other tools).

The detector is an open single-sided disk (a sheet of triangles) at z = 0 facing +z,
filling the end plate's hole.
"""
from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from geometry.mesh import GeometryError
from geometry.parts import ShapePart, require_positive
from geometry.parts.detector import disk_detector
from geometry.parts.stops import annular_plate

BEVEL_SIDES = ("back", "front")


@dataclass(frozen=True)
class TubeParams:
    """Parameters of :func:`build_tube`; the defaults are the BENCHMARK.md reference tube.

    inner_radius_mm, length_mm, wall_thickness_mm : wall annulus r = inner .. inner + thickness, z = 0 .. length
    vane_count : number of vanes (0 allowed)
    vane_z_mm : centre z of each vane (when given, it sets ``vane_count``), or None for ``vane_count``
        vanes evenly spaced from ``vane_first_z_mm`` to ``vane_last_z_mm`` (a single vane sits at
        ``vane_last_z_mm``, nearest the entrance)
    vane_inner_radius_mm : radius of the vane hole; vanes run out to the wall's inner radius
    vane_thickness_mm : axial thickness of each vane
    vane_bevel_deg : bevel on the vane's inner edge: the inner face is a cone at this angle to the
        tube axis (0 = square edge, a cylinder). The edge stays sharp at ``vane_inner_radius_mm`` on
        the un-bevelled face; the other face starts at ``vane_inner_radius_mm + thickness * tan(bevel)``.
    vane_bevel_side : "back" (the bevel faces the detector, -z; knife edge on the entrance side) or "front"
    end_plate_thickness_mm : end plate r = field_stop_radius_mm .. outer wall radius, z = -thickness .. 0
    field_stop_radius_mm : radius of the end plate's hole
    aperture_stop_radius_mm : None (open entrance) or the hole radius of a stop on the wall rim,
        z = length .. length + aperture_stop_thickness_mm, outer radius = outer wall radius
    detector_radius_mm : detector disk radius at z = 0 (None: equal to ``field_stop_radius_mm``)
    """

    inner_radius_mm: float = 50.0
    length_mm: float = 300.0
    wall_thickness_mm: float = 1.0
    vane_count: int = 7
    vane_z_mm: tuple[float, ...] | None = None
    vane_first_z_mm: float = 40.0
    vane_last_z_mm: float = 280.0
    vane_inner_radius_mm: float = 35.0
    vane_thickness_mm: float = 1.0
    vane_bevel_deg: float = 0.0
    vane_bevel_side: str = "back"
    end_plate_thickness_mm: float = 1.0
    field_stop_radius_mm: float = 35.0
    aperture_stop_radius_mm: float | None = None
    aperture_stop_thickness_mm: float = 1.0
    detector_radius_mm: float | None = None

    def __post_init__(self):
        if self.vane_z_mm is not None:
            object.__setattr__(self, "vane_z_mm", tuple(float(z) for z in np.atleast_1d(self.vane_z_mm)))
            object.__setattr__(self, "vane_count", len(self.vane_z_mm))
        self.validate()

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))

    @property
    def outer_radius_mm(self) -> float:
        return self.inner_radius_mm + self.wall_thickness_mm

    @property
    def vane_centres_mm(self) -> tuple[float, ...]:
        """Centre z of every vane, ascending (vane_1 is the lowest, nearest the detector)."""
        if self.vane_z_mm is not None:
            return tuple(sorted(self.vane_z_mm))
        if self.vane_count == 1:
            return (float(self.vane_last_z_mm),)
        return tuple(float(z) for z in np.linspace(self.vane_first_z_mm, self.vane_last_z_mm, self.vane_count))

    @property
    def detector_radius(self) -> float:
        return self.field_stop_radius_mm if self.detector_radius_mm is None else self.detector_radius_mm

    def validate(self):
        """Raise GeometryError naming the first inconsistent parameter."""
        require_positive(inner_radius_mm=self.inner_radius_mm, length_mm=self.length_mm,
                         wall_thickness_mm=self.wall_thickness_mm, vane_inner_radius_mm=self.vane_inner_radius_mm,
                         vane_thickness_mm=self.vane_thickness_mm, end_plate_thickness_mm=self.end_plate_thickness_mm,
                         field_stop_radius_mm=self.field_stop_radius_mm,
                         aperture_stop_thickness_mm=self.aperture_stop_thickness_mm)
        if int(self.vane_count) != self.vane_count or self.vane_count < 0:
            raise GeometryError(f"vane_count must be an integer >= 0, got {self.vane_count!r}")
        if not self.vane_inner_radius_mm < self.inner_radius_mm:
            raise GeometryError(f"vane_inner_radius_mm ({self.vane_inner_radius_mm}) must be below inner_radius_mm "
                                f"({self.inner_radius_mm})")
        if not self.field_stop_radius_mm < self.outer_radius_mm:
            raise GeometryError(f"field_stop_radius_mm ({self.field_stop_radius_mm}) must be below the outer wall "
                                f"radius ({self.outer_radius_mm})")
        if not (0.0 <= self.vane_bevel_deg < 90.0):
            raise GeometryError(f"vane_bevel_deg must be in [0, 90), got {self.vane_bevel_deg!r}")
        if self.vane_bevel_side not in BEVEL_SIDES:
            raise GeometryError(f"vane_bevel_side must be one of {', '.join(BEVEL_SIDES)}, "
                                f"got {self.vane_bevel_side!r}")
        run_mm = self.vane_thickness_mm * np.tan(np.deg2rad(self.vane_bevel_deg))
        if run_mm >= self.inner_radius_mm - self.vane_inner_radius_mm:
            raise GeometryError(f"vane_bevel_deg ({self.vane_bevel_deg}) too steep: the bevel runs {run_mm:.3g} mm, "
                                f"deeper than the vane ({self.inner_radius_mm - self.vane_inner_radius_mm:.3g} mm)")
        if self.aperture_stop_radius_mm is not None:
            require_positive(aperture_stop_radius_mm=self.aperture_stop_radius_mm)
            if not self.aperture_stop_radius_mm < self.outer_radius_mm:
                raise GeometryError(f"aperture_stop_radius_mm ({self.aperture_stop_radius_mm}) must be below the "
                                    f"outer wall radius ({self.outer_radius_mm})")
        if self.detector_radius_mm is not None:
            require_positive(detector_radius_mm=self.detector_radius_mm)
        if self.detector_radius > self.field_stop_radius_mm:
            raise GeometryError(f"detector_radius_mm ({self.detector_radius}) must not exceed field_stop_radius_mm "
                                f"({self.field_stop_radius_mm}): the detector fills the end plate's hole")
        half = self.vane_thickness_mm / 2
        z = np.array(self.vane_centres_mm)
        if len(z):
            if z.min() - half <= 0 or z.max() + half >= self.length_mm:
                raise GeometryError(f"vane positions must lie inside the tube (0 < z +- {half} < {self.length_mm} mm), "
                                    f"got {z.min():g} .. {z.max():g}")
            if len(z) > 1 and np.diff(z).min() <= self.vane_thickness_mm:
                raise GeometryError(f"vanes overlap: centres {np.diff(z).min():g} mm apart, thickness "
                                    f"{self.vane_thickness_mm} mm")


REFERENCE_TUBE = TubeParams()
"""BENCHMARK.md: wall r 50..51, z 0..300; vanes r 35..50, 1 mm thick at z = 40, 80, .., 280;
end plate r 35..51, z -1..0; detector r < 35 at z = 0 facing +z."""


def vane(inner_radius_mm: float, outer_radius_mm: float, thickness_mm: float, centre_z_mm: float,
         bevel_deg: float = 0.0, bevel_side: str = "back", *, name: str = "vane") -> ShapePart:
    """One annular vane centred at ``centre_z_mm``; see :class:`TubeParams` for the bevel."""
    import cadquery as cq

    half = thickness_mm / 2
    if bevel_deg == 0:
        return annular_plate(inner_radius_mm, outer_radius_mm, thickness_mm, centre_z_mm + half, name=name)
    run_mm = thickness_mm * np.tan(np.deg2rad(bevel_deg))
    sharp, bevelled = (half, -half) if bevel_side == "back" else (-half, half)
    # (r, z) profile revolved about the z axis; on the "XZ" workplane local y is global z.
    profile = [(inner_radius_mm, sharp), (outer_radius_mm, sharp), (outer_radius_mm, bevelled),
               (inner_radius_mm + run_mm, bevelled)]
    solid = (cq.Workplane("XZ").polyline([(r, centre_z_mm + z) for r, z in profile]).close()
             .revolve(360.0, (0, 0, 0), (0, 1, 0)).val())
    return ShapePart(name, solid, "surface", "solid")


def build_tube(params: TubeParams = REFERENCE_TUBE) -> dict[str, ShapePart]:
    """Named parts of a baffled tube, in order: wall, vane_1..vane_N, end_plate, [aperture_stop], detector."""
    p = params
    parts = [annular_plate(p.inner_radius_mm, p.outer_radius_mm, p.length_mm, p.length_mm, name="wall")]
    for k, z in enumerate(p.vane_centres_mm, start=1):
        parts.append(vane(p.vane_inner_radius_mm, p.inner_radius_mm, p.vane_thickness_mm, z, p.vane_bevel_deg,
                          p.vane_bevel_side, name=f"vane_{k}"))
    parts.append(annular_plate(p.field_stop_radius_mm, p.outer_radius_mm, p.end_plate_thickness_mm, 0.0,
                               name="end_plate"))
    if p.aperture_stop_radius_mm is not None:
        parts.append(annular_plate(p.aperture_stop_radius_mm, p.outer_radius_mm, p.aperture_stop_thickness_mm,
                                   p.length_mm + p.aperture_stop_thickness_mm, name="aperture_stop"))
    parts.append(disk_detector(p.detector_radius, name="detector"))
    return {part.name: part for part in parts}


def reference_tube() -> dict[str, ShapePart]:
    """Exactly the BENCHMARK.md tube (separate touching parts, detector as an open disk at z = 0 facing +z)."""
    return build_tube(REFERENCE_TUBE)


def fuse_solids(parts: dict[str, ShapePart], *, name: str = "tube") -> ShapePart:
    """One solid: the CadQuery boolean union of every solid part (sheets are left out)."""
    solids = [p.shape for p in parts.values() if p.kind == "solid"]
    if not solids:
        raise GeometryError("fuse_solids: no solid parts to fuse")
    fused = solids[0].fuse(*solids[1:]).clean() if len(solids) > 1 else solids[0]
    return ShapePart(name, fused, "surface", "solid")
