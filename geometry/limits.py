"""Chord tolerances that would mesh without bound, refused before meshing.

OpenCascade meshes to whatever chord error it is asked for, in native code that neither reports
progress nor stops on Ctrl-C: ``--tolerance-mm 1e-6`` on a 100 mm part asks for ~1e8 triangles.
Two checks, both before any meshing:

- a floor, :data:`MIN_TOLERANCE_MM` (10 nm: far below the form error of any machined or
  diamond-turned part; exact optical shapes come from analytic surfaces, CONTRACTS §6.1), applied
  wherever a tolerance enters (command line, scene file);
- an estimate of the triangle count from each shape's size: a sphere of radius R meshed to chord
  error t has triangles of edge s = 2 sqrt(2 R t) (the chord whose sagitta is t), area about
  (sqrt(3)/4) s^2 = 2 sqrt(3) R t, so about 4 pi R^2 / (2 sqrt(3) R t) = 3.63 R / t of them. With
  R = half the shape's bounding-box diagonal (the most curved surface that fits), summed over the
  shapes, a request above :func:`max_triangles` (this machine's memory at ~1 KB per triangle while
  OpenCascade meshes) is refused in one line with the estimate.
"""
from __future__ import annotations

import math

MIN_TOLERANCE_MM = 1e-5
MAX_TEMPERATURE_K = 1e5  # hotter than any star's surface; above ~1e8 K Planck's band fractions cancel to 0 W
MAX_COORDINATE_MM = 1e7  # 10 km: float32 (Embree, the tracer's intersector) spaces numbers 1 mm apart there
BYTES_PER_TRIANGLE_MESHING = 1024  # OCC's mesh structures + our arrays, per triangle, while meshing


class ToleranceError(ValueError):
    """A chord tolerance that is not a usable number, or would mesh beyond this machine."""


def temperature_limit_message(value: float) -> str | None:
    """The reason a ``temperature_k`` is refused, or None: above :data:`MAX_TEMPERATURE_K` the band
    radiance is the difference of two blackbody fractions within round-off of 1 (straylight.thermal.planck),
    so 1e9 K gave 0 W and 1e300 K an index error."""
    if value > MAX_TEMPERATURE_K:
        return (f"temperature_k = {value:g} K is above the {MAX_TEMPERATURE_K:g} K limit (hotter than any star's "
                f"surface; Planck's band radiance is not computable there)")
    return None


def coordinate_limit_message(value: float, what: str) -> str | None:
    """The one-line reason a position or length ``value`` (mm) is refused, or None if it is usable.

    Beyond :data:`MAX_COORDINATE_MM` (10 km) float32, in which Embree intersects rays, spaces numbers
    by 1 mm or more, and the tracer's self-intersection offset (32 float32 ulps of the largest
    coordinate, straylight.engine.spec.scene_epsilon) grows past 32 mm: a part moved 1e9 mm away
    made every detector read 0 W. No instrument part is that far or that large."""
    if abs(value) > MAX_COORDINATE_MM:
        return (f"{what} = {value:g} mm is beyond the {MAX_COORDINATE_MM:g} mm (10 km) the tracer's float32 "
                f"intersector resolves to better than 1 mm; keep parts within 10 km of the origin")
    return None


def check_tolerance_mm(value, where: str = "tolerance_mm") -> float:
    """``value`` as a float if it is finite and >= :data:`MIN_TOLERANCE_MM`; else a one-line error."""
    try:
        t = float(value)
    except (TypeError, ValueError):
        raise ToleranceError(f"{where}: chord tolerance must be a number, got {value!r}") from None
    if not math.isfinite(t) or t <= 0:
        raise ToleranceError(f"{where}: chord tolerance must be a positive number of mm, got {value!r}")
    if t < MIN_TOLERANCE_MM:
        raise ToleranceError(f"{where}: chord tolerance {t:g} mm is below {MIN_TOLERANCE_MM:g} mm (10 nm): it would "
                             f"mesh without bound; exact optical shapes come from analytic surfaces (docs/reference/scene.md)")
    return t


def estimated_triangles(size_mm: float, tolerance_mm: float) -> float:
    """Triangles of the most curved surface a box of diagonal ``size_mm`` holds (a sphere of radius
    size / 2) meshed to chord error ``tolerance_mm``: 3.63 R / t (module doc)."""
    radius_mm = 0.5 * float(size_mm)
    return 4.0 * math.pi / (2.0 * math.sqrt(3.0)) * radius_mm / float(tolerance_mm)


def max_triangles() -> float:
    """Triangles this machine can mesh in memory (:data:`BYTES_PER_TRIANGLE_MESHING` each); inf if unknown."""
    from atomicio.inputs import physical_memory_bytes

    memory = physical_memory_bytes()
    return memory / BYTES_PER_TRIANGLE_MESHING if memory else math.inf


def shape_size_mm(shape) -> float:
    """Bounding-box diagonal of a CadQuery shape, Workplane or OCP TopoDS_Shape (mm; 0 if empty)."""
    from OCP.Bnd import Bnd_Box
    from OCP.BRepBndLib import BRepBndLib

    wrapped = getattr(shape, "wrapped", shape)
    if hasattr(shape, "val") and not hasattr(shape, "wrapped"):  # a Workplane
        wrapped = shape.val().wrapped
    box = Bnd_Box()
    BRepBndLib.Add_s(wrapped, box, False)  # from the B-rep geometry, no triangulation needed
    if box.IsVoid():
        return 0.0
    x0, y0, z0, x1, y1, z1 = box.Get()
    return math.sqrt((x1 - x0) ** 2 + (y1 - y0) ** 2 + (z1 - z0) ** 2)


def check_mesh_budget(shapes, tolerance_mm: float, where: str) -> float:
    """Refuse meshing ``shapes`` at ``tolerance_mm`` when the estimated triangle count (module doc,
    summed over the shapes) exceeds :func:`max_triangles`; returns the estimate."""
    t = check_tolerance_mm(tolerance_mm, where)
    total = sum(estimated_triangles(shape_size_mm(s), t) for s in shapes)
    limit = max_triangles()
    if total > limit:
        raise ToleranceError(f"{where}: chord tolerance {t:g} mm could give about {total:.2g} triangles, more than "
                             f"this machine can mesh (~{limit:.2g}); use a larger tolerance_mm")
    return total
