"""A realistic multi-part telescope tube assembly with hooked vanes (the issue-12 benchmark scene).

It stands in for a tube as a user's CAD tool would export it: many separate named solids, curved
surfaces of every common kind (cylinders, cones, tori from the hub's rounded front, an ellipse where the
spider's hub is cut at 45 deg, bolt holes), and a detector that is a thin *closed* disk (front,
back, rim) as CAD gives it.

Frame as the built-in tube: z is the tube axis, light enters at the top (z = length + stop) and
travels toward -z; the detector's front face is the disk r < ``field_stop_radius_mm`` at z = 0.

Parts (in order; names are the STEP assembly's product names):

- ``section_1`` .. ``section_N``: wall sections r = R .. R + w, each ``section_length_mm`` long, with a
  flange ring at both ends (r out to R + w + ``flange_width_mm``) drilled with ``bolt_count`` holes;
  flanges of neighbouring sections touch.
- ``vane_1`` (lowest) .. ``vane_M``: hooked vanes. A flat annulus r = ``vane_inner_radius_mm`` .. R
  (touching the wall), ``vane_thickness_mm`` thick, with a lip on its inner edge rising
  ``hook_length_mm`` toward the entrance, ``hook_thickness_mm`` thick radially, leaning
  ``hook_angle_deg`` outward (toward the wall: the lip and plate form a light trap); its tip is
  square, or rounded (a thin torus) with ``hook_round_tip`` -- OpenCascade meshes such thin tori
  badly (6-9x the asked deflection until refined), so that costs many triangles. Vanes (and the
  spider's legs) stop ``vane_clearance_mm`` short of the wall, as a fitted part does: touching
  curved parts would overlap by the chord error of their meshes.
- ``spider``: a hub (cylinder of ``hub_radius_mm``, its front edge rounded with ``hub_fillet_mm``: a
  torus; its bottom cut at 45 deg: an elliptical flat, the secondary-mirror face of a Newtonian) held by ``spider_leg_count`` thin legs reaching the wall.
- ``entrance_stop``: annulus r = ``entrance_radius_mm`` .. flange radius on the top rim.
- ``end_plate``: annulus r = ``field_stop_radius_mm`` .. flange radius, z = -thickness .. 0.
- ``detector``: the disk r < ``field_stop_radius_mm``, z = -``detector_thickness_mm`` .. 0 (a closed
  thin solid, role "detector"); ``detector_kind="sheet"`` gives the open one-sided disk instead.

``hooked_tube_assembly()`` gives the CadQuery parts, ``hooked_tube_scene()`` the tessellated scene
(about 0.4M triangles at ``BENCHMARK_TOLERANCE_MM``), ``export_hooked_tube()`` a named STEP assembly,
the meshes and a scene.toml with a ``collimated_disk`` source. ``SMALL`` is a few-thousand-triangle
variant for tests.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

import numpy as np

import atomicio
from geometry.mesh import GeometryError
from geometry.parts import ShapePart, require_positive

DETECTOR_KINDS = ("solid", "sheet")
BENCHMARK_TOLERANCE_MM = 0.002
"""Chord tolerance at which the default assembly has about 0.4M triangles (see docs/geometry.md)."""
BEAM_STANDOFF_MM = 10.0


_MAY_BE_ZERO = ("hub_fillet_mm", "vane_clearance_mm")
_ANY_SIGN = ("vane_first_z_mm", "vane_last_z_mm", "spider_z_mm")


@dataclass(frozen=True)
class HookedTubeParams:
    """Parameters of :func:`hooked_tube_assembly` (lengths mm, angles deg); defaults: a 120 mm tube,
    11 sections, 36 hooked vanes, a 4-leg spider."""

    inner_radius_mm: float = 60.0
    wall_thickness_mm: float = 1.5
    section_count: int = 11
    section_length_mm: float = 60.0
    flange_width_mm: float = 6.0
    flange_thickness_mm: float = 3.0
    bolt_count: int = 8
    bolt_radius_mm: float = 1.6
    vane_count: int = 36
    vane_first_z_mm: float = 30.0
    vane_last_z_mm: float = 600.0
    vane_inner_radius_mm: float = 45.0
    vane_thickness_mm: float = 1.0
    hook_length_mm: float = 4.0
    hook_thickness_mm: float = 0.8
    hook_angle_deg: float = 20.0
    hook_round_tip: bool = False
    vane_clearance_mm: float = 0.05
    spider_leg_count: int = 4
    spider_z_mm: float = 630.0
    spider_leg_thickness_mm: float = 1.0
    spider_leg_height_mm: float = 10.0
    hub_radius_mm: float = 15.0
    hub_length_mm: float = 30.0
    hub_fillet_mm: float = 3.0
    entrance_radius_mm: float = 58.0
    entrance_stop_thickness_mm: float = 1.5
    field_stop_radius_mm: float = 40.0
    end_plate_thickness_mm: float = 2.0
    detector_thickness_mm: float = 0.5
    detector_kind: str = "solid"

    def __post_init__(self):
        self.validate()

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))

    @property
    def length_mm(self) -> float:
        return self.section_count * self.section_length_mm

    @property
    def flange_radius_mm(self) -> float:
        return self.inner_radius_mm + self.wall_thickness_mm + self.flange_width_mm

    @property
    def top_z_mm(self) -> float:
        return self.length_mm + self.entrance_stop_thickness_mm

    @property
    def vane_centres_mm(self) -> tuple[float, ...]:
        if self.vane_count == 1:
            return (float(self.vane_last_z_mm),)
        return tuple(float(z) for z in np.linspace(self.vane_first_z_mm, self.vane_last_z_mm, self.vane_count))

    def validate(self):
        """Raise GeometryError naming the first inconsistent parameter."""
        positive = {f.name: getattr(self, f.name) for f in fields(self)
                    if f.name.endswith("_mm") and f.name not in _MAY_BE_ZERO + _ANY_SIGN}
        require_positive(**positive)
        for key in _MAY_BE_ZERO:
            if not (np.isfinite(getattr(self, key)) and getattr(self, key) >= 0):
                raise GeometryError(f"{key} must be a finite number >= 0, got {getattr(self, key)!r}")
        for key in ("section_count", "vane_count", "spider_leg_count", "bolt_count"):
            value = getattr(self, key)
            if int(value) != value or value < (1 if key == "section_count" else 0):
                raise GeometryError(f"{key} must be an integer >= {1 if key == 'section_count' else 0}, got {value!r}")
        if self.detector_kind not in DETECTOR_KINDS:
            raise GeometryError(f"detector_kind must be one of {', '.join(DETECTOR_KINDS)}, got {self.detector_kind!r}")
        r, r_v = self.inner_radius_mm, self.vane_inner_radius_mm
        if not r_v + self.hook_thickness_mm < r:
            raise GeometryError(f"vane_inner_radius_mm + hook_thickness_mm ({r_v + self.hook_thickness_mm:g}) must be "
                                f"below inner_radius_mm ({r:g})")
        if not 0 <= self.hook_angle_deg < 80:
            raise GeometryError(f"hook_angle_deg must be in [0, 80), got {self.hook_angle_deg!r}")
        lean_mm = self.hook_length_mm * np.tan(np.deg2rad(self.hook_angle_deg))
        if r_v + self.hook_thickness_mm + lean_mm >= r:
            raise GeometryError(f"hook_angle_deg ({self.hook_angle_deg:g}) too large: the lip leans into the wall")
        if not self.field_stop_radius_mm < r + self.wall_thickness_mm:
            raise GeometryError(f"field_stop_radius_mm ({self.field_stop_radius_mm:g}) must be below the outer wall "
                                f"radius ({r + self.wall_thickness_mm:g})")
        if not self.entrance_radius_mm < self.flange_radius_mm:
            raise GeometryError(f"entrance_radius_mm ({self.entrance_radius_mm:g}) must be below the flange radius "
                                f"({self.flange_radius_mm:g})")
        if not self.hub_radius_mm < r:
            raise GeometryError(f"hub_radius_mm ({self.hub_radius_mm:g}) must be below inner_radius_mm ({r:g})")
        if 2 * self.flange_thickness_mm >= self.section_length_mm:
            raise GeometryError(f"flange_thickness_mm ({self.flange_thickness_mm:g}) too large for section_length_mm "
                                f"({self.section_length_mm:g})")
        if self.bolt_count and not 2 * self.bolt_radius_mm < self.flange_width_mm:
            raise GeometryError(f"bolt_radius_mm ({self.bolt_radius_mm:g}) too large for flange_width_mm "
                                f"({self.flange_width_mm:g})")
        spider_lo = self.spider_z_mm - max(self.hub_length_mm, self.spider_leg_height_mm) / 2
        spider_hi = self.spider_z_mm + max(self.hub_length_mm, self.spider_leg_height_mm) / 2
        if self.spider_leg_count and not (0 < spider_lo and spider_hi < self.length_mm):
            raise GeometryError(f"spider_z_mm ({self.spider_z_mm:g}): the spider must lie inside the tube "
                                f"(0 .. {self.length_mm:g} mm)")
        if self.vane_count:
            z = np.array(self.vane_centres_mm)
            lo = z.min() - self.vane_thickness_mm / 2
            hi = z.max() + self.vane_thickness_mm / 2 + self.hook_length_mm + self.hook_thickness_mm / 2
            if lo <= 0 or hi >= self.length_mm:
                raise GeometryError(f"vanes must lie inside the tube (0 .. {self.length_mm:g} mm), "
                                    f"got {lo:g} .. {hi:g}")
            pitch = self.vane_thickness_mm + self.hook_length_mm + self.hook_thickness_mm
            if len(z) > 1 and np.diff(z).min() <= pitch:
                raise GeometryError(f"vanes overlap: centres {np.diff(z).min():g} mm apart, each vane with its hook is "
                                    f"{pitch:g} mm tall")
            if self.spider_leg_count and hi >= spider_lo:
                raise GeometryError(f"the last vane (top {hi:g} mm) reaches the spider (bottom {spider_lo:g} mm)")


DEFAULT = HookedTubeParams()
SMALL = HookedTubeParams(section_count=3, section_length_mm=60.0, bolt_count=4, vane_count=4, vane_first_z_mm=30.0,
                         vane_last_z_mm=130.0, spider_leg_count=3, spider_z_mm=160.0)
"""A 3-section, 4-vane, 3-leg variant: a few thousand triangles at 0.05 mm (tests)."""


def _revolve(profile_rz, *, arc=None):
    """A solid of revolution about z from a closed (r, z) polyline; ``arc = (i, mid)`` replaces the
    segment from point i to point i + 1 by a three-point arc through ``mid``."""
    import cadquery as cq

    wp = cq.Workplane("XZ").moveTo(*profile_rz[0])
    for i in range(1, len(profile_rz)):
        if arc is not None and arc[0] == i - 1:
            wp = wp.threePointArc(tuple(arc[1]), tuple(profile_rz[i]))
        else:
            wp = wp.lineTo(*profile_rz[i])
    return wp.close().revolve(360.0, (0, 0, 0), (0, 1, 0)).val()


def hooked_vane(p: HookedTubeParams, centre_z_mm: float, *, name: str) -> ShapePart:
    """One hooked vane centred at ``centre_z_mm`` (see the module docstring)."""
    r_in, r_wall, half = p.vane_inner_radius_mm, p.inner_radius_mm - p.vane_clearance_mm, p.vane_thickness_mm / 2
    a = np.deg2rad(p.hook_angle_deg)
    u = np.array([np.sin(a), np.cos(a)])  # the lip's direction in (r, z)
    top = centre_z_mm + half
    lip_outer = np.array([r_in + p.hook_thickness_mm, top]) + p.hook_length_mm * u
    lip_inner = np.array([r_in, top]) + p.hook_length_mm * u
    tip = (lip_outer + lip_inner) / 2 + p.hook_thickness_mm / 2 * u
    profile = [(r_in, centre_z_mm - half), (r_wall, centre_z_mm - half), (r_wall, top),
               (r_in + p.hook_thickness_mm, top), tuple(lip_outer), tuple(lip_inner)]
    if p.hook_angle_deg > 0:
        profile.append((r_in, top))
    return ShapePart(name, _revolve(profile, arc=(4, tip) if p.hook_round_tip else None), "surface", "solid")


def tube_section(p: HookedTubeParams, index: int, *, name: str) -> ShapePart:
    """Wall section ``index`` (0-based) with its two drilled flanges."""
    import cadquery as cq

    z0 = index * p.section_length_mm
    z1 = z0 + p.section_length_mm
    r, r_out, r_f, t = p.inner_radius_mm, p.inner_radius_mm + p.wall_thickness_mm, p.flange_radius_mm, \
        p.flange_thickness_mm
    profile = [(r, z0), (r_f, z0), (r_f, z0 + t), (r_out, z0 + t), (r_out, z1 - t), (r_f, z1 - t), (r_f, z1), (r, z1)]
    solid = _revolve(profile)
    if p.bolt_count:
        r_bolt = (r_out + r_f) / 2
        holes = (cq.Workplane("XY").workplane(offset=z0 - 1).polarArray(r_bolt, 0, 360, p.bolt_count)
                 .circle(p.bolt_radius_mm).extrude(p.section_length_mm + 2).val())
        solid = solid.cut(holes).clean()
    return ShapePart(name, solid, "surface", "solid")


def spider(p: HookedTubeParams, *, name: str = "spider") -> ShapePart:
    """Hub with a 45-deg elliptical bottom face, held by ``spider_leg_count`` legs touching the wall."""
    import cadquery as cq

    z, r = p.spider_z_mm, p.inner_radius_mm
    hub = cq.Solid.makeCylinder(p.hub_radius_mm, p.hub_length_mm, cq.Vector(0, 0, z - p.hub_length_mm / 2))
    if p.hub_fillet_mm:
        top = [e for e in hub.Edges() if e.Center().z > z + p.hub_length_mm / 2 - 1e-6]
        hub = hub.fillet(p.hub_fillet_mm, top)
    # Cut the hub's bottom with a plane at 45 deg to the axis through (0, 0, z - hub_length / 4).
    cutter = cq.Solid.makeBox(8 * p.hub_radius_mm, 8 * p.hub_radius_mm, 4 * p.hub_radius_mm,
                              cq.Vector(-4 * p.hub_radius_mm, -4 * p.hub_radius_mm, -4 * p.hub_radius_mm))
    cutter = cutter.rotate(cq.Vector(0, 0, 0), cq.Vector(1, 0, 0), 45).translate(
        cq.Vector(0, 0, z - p.hub_length_mm / 4))
    body = hub.cut(cutter)
    legs = []
    for k in range(p.spider_leg_count):
        leg = cq.Solid.makeBox(r + 1.0, p.spider_leg_thickness_mm, p.spider_leg_height_mm,
                               cq.Vector(0, -p.spider_leg_thickness_mm / 2, z - p.spider_leg_height_mm / 2))
        legs.append(leg.rotate(cq.Vector(0, 0, 0), cq.Vector(0, 0, 1), 45.0 + 360.0 * k / p.spider_leg_count))
    if legs:
        bound = cq.Solid.makeCylinder(r - p.vane_clearance_mm, 2 * p.spider_leg_height_mm, cq.Vector(0, 0, z - p.spider_leg_height_mm))
        body = body.fuse(*[leg.intersect(bound) for leg in legs])
    body = body.clean()
    solids = body.Solids()
    if len(solids) != 1:
        raise GeometryError(f"{name}: the hub and legs did not fuse into one solid ({len(solids)} solids)")
    return ShapePart(name, solids[0], "surface", "solid")


def _annulus(inner_mm, outer_mm, z0_mm, z1_mm, name, role="surface") -> ShapePart:
    return ShapePart(name, _revolve([(inner_mm, z0_mm), (outer_mm, z0_mm), (outer_mm, z1_mm), (inner_mm, z1_mm)]),
                     role, "solid")


def detector(p: HookedTubeParams, *, name: str = "detector") -> ShapePart:
    """The detector: a thin closed disk (front face z = 0) or, with ``detector_kind="sheet"``, the open disk."""
    import cadquery as cq

    r = p.field_stop_radius_mm
    if p.detector_kind == "sheet":
        face = cq.Face.makeFromWires(cq.Wire.makeCircle(r, cq.Vector(0, 0, 0), cq.Vector(0, 0, 1)))
        return ShapePart(name, face, "detector", "sheet")
    solid = cq.Solid.makeCylinder(r, p.detector_thickness_mm, cq.Vector(0, 0, -p.detector_thickness_mm))
    return ShapePart(name, solid, "detector", "solid")


def hooked_tube_assembly(params: HookedTubeParams | None = None, **overrides) -> dict[str, ShapePart]:
    """Named CadQuery parts of the hooked-vane tube: section_1..N, vane_1..M, spider, entrance_stop,
    end_plate, detector. ``overrides`` are :class:`HookedTubeParams` fields (e.g. ``vane_count=12``)."""
    p = params or DEFAULT
    if overrides:
        unknown = set(overrides) - set(HookedTubeParams.names())
        if unknown:
            raise GeometryError(f"unknown assembly parameter(s): {', '.join(sorted(unknown))}; "
                                f"known: {', '.join(HookedTubeParams.names())}")
        p = replace(p, **overrides)
    parts = [tube_section(p, i, name=f"section_{i + 1}") for i in range(p.section_count)]
    parts += [hooked_vane(p, z, name=f"vane_{k}") for k, z in enumerate(p.vane_centres_mm, start=1)]
    if p.spider_leg_count:
        parts.append(spider(p))
    parts.append(_annulus(p.entrance_radius_mm, p.flange_radius_mm, p.length_mm, p.top_z_mm, "entrance_stop"))
    parts.append(_annulus(p.field_stop_radius_mm, p.flange_radius_mm, -p.end_plate_thickness_mm, 0.0, "end_plate"))
    parts.append(detector(p))
    return {part.name: part for part in parts}


def collimated_source(p: HookedTubeParams = DEFAULT, power_w: float = 1.0) -> dict:
    """The scene's on-axis beam (CONTRACTS §6): a disk just above the entrance stop covering the flanges."""
    return {"type": "collimated_disk", "center_mm": [0.0, 0.0, p.top_z_mm + BEAM_STANDOFF_MM],
            "normal": [0.0, 0.0, -1.0], "direction": [0.0, 0.0, -1.0], "radius_mm": float(p.flange_radius_mm),
            "power_w": float(power_w)}


def hooked_tube_scene(params: HookedTubeParams | None = None, *, tolerance_mm: float = BENCHMARK_TOLERANCE_MM,
                      angular_tolerance_deg: float = 10.0, material: str | None = "z302_sample_b", **overrides):
    """The tessellated assembly (a :class:`geometry.mesh.Scene`); the detector has no material."""
    from geometry.tessellate import tessellate_parts

    return tessellate_parts(hooked_tube_assembly(params, **overrides), tolerance_mm=tolerance_mm,
                            angular_tolerance_deg=angular_tolerance_deg, material=material)


def export_hooked_tube(directory, params: HookedTubeParams | None = None, *,
                       tolerance_mm: float = BENCHMARK_TOLERANCE_MM, material: str = "z302_sample_b",
                       mesh_format: str = "ply", **overrides) -> Path:
    """Write ``assembly.step`` (one named STEP assembly), one mesh per part and ``scene.toml`` (meshes,
    roles, material, the collimated source, and an ``[analysis]``-free part list). Returns the TOML path."""
    from geometry.io import export_assembly_step, save_scene

    p = params or DEFAULT
    if overrides:
        p = replace(p, **overrides)
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    shape_parts = hooked_tube_assembly(p)
    export_assembly_step(shape_parts, directory / "assembly.step")
    scene = hooked_tube_scene(p, tolerance_mm=tolerance_mm, material=material)
    path = save_scene(scene, directory, mesh_format=mesh_format, sources=[collimated_source(p)])
    atomicio.write_json(directory / "params.json", asdict(p), final_newline=False)
    return path
