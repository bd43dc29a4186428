"""The built-in baffled tube set up for analyses: scene, materials, beam and entrance.

The default is the reference tube of ``shared/BENCHMARK.md`` (wall r 50..51 mm, 300 mm
long, 7 vanes with r = 35 mm holes, end plate, detector r < 35 mm at z = 0 facing +z),
coated with the ``z302_sample_b`` preset. The beam is a disk 10 mm above the entrance,
perpendicular to the tube axis, of the wall's outer radius (51 mm); tilted, it slides in its
plane so that its central ray still passes through the entrance centre, so it always covers
the entrance and the rim exactly. BENCHMARK.md launches rays over r < 60 mm at z = 310 mm;
the extra rays there meet only the outer wall, whose normal faces away from every other
surface, so they cannot reach the detector: the ratios are the same in expectation, and
no ray is spent on them.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np

DEFAULT_MATERIAL = "z302_sample_b"
DEFAULT_TOLERANCE_MM = 0.05
BEAM_STANDOFF_MM = 10.0


@dataclass(frozen=True, eq=False)
class Beam:
    """A collimated beam: rays start uniformly over a fixed disk.

    center_mm : (3,) disk centre
    axis : (3,) unit vector, disk normal and the beam direction at 0 deg off axis
        (pointing into the instrument)
    radius_mm : disk radius
    power_w : power leaving the disk
    pivot_mm : (3,) or None. None: the disk stays at ``center_mm`` for every tilt
        (BENCHMARK.md). A point: the disk slides in its own plane so that the ray through
        its centre passes through the pivot (keeps a tilted beam on the entrance).
    disk_normal : (3,) or None: normal of the emitting disk when it is not ``axis`` (a scene's
        collimated_disk source may emit obliquely through its disk); None: ``axis``.
    """

    center_mm: np.ndarray
    axis: np.ndarray
    radius_mm: float
    power_w: float = 1.0
    pivot_mm: np.ndarray | None = None
    disk_normal: np.ndarray | None = None
    wavelength_nm: float | None = None  # the source's (CONTRACTS §6.5), carried to every tilt

    def __post_init__(self):
        axis = np.asarray(self.axis, dtype=np.float64)
        norm = np.linalg.norm(axis)
        if axis.shape != (3,) or not np.isfinite(norm) or norm == 0:
            raise ValueError(f"beam axis must be 3 finite numbers, not all zero, got {self.axis!r}")
        object.__setattr__(self, "axis", axis / norm)
        object.__setattr__(self, "center_mm", np.asarray(self.center_mm, dtype=np.float64).reshape(3))
        if self.pivot_mm is not None:
            object.__setattr__(self, "pivot_mm", np.asarray(self.pivot_mm, dtype=np.float64).reshape(3))
        if not (np.isfinite(self.radius_mm) and self.radius_mm > 0):
            raise ValueError(f"beam radius_mm must be > 0, got {self.radius_mm!r}")
        n = self.axis if self.disk_normal is None else np.asarray(self.disk_normal, dtype=np.float64).reshape(3)
        if not np.isfinite(np.linalg.norm(n)) or abs(float(np.dot(n, self.axis))) < 1e-9 * np.linalg.norm(n):
            raise ValueError(f"beam disk normal {self.disk_normal!r} must not be perpendicular to the beam")
        object.__setattr__(self, "disk_normal", n / np.linalg.norm(n))

    @property
    def basis(self) -> tuple[np.ndarray, np.ndarray]:
        """(e1, e2): unit vectors perpendicular to ``axis``; azimuth 0 tilts toward e1.

        e1 is the world axis least aligned with ``axis``, made orthogonal to it, and
        e2 = e1 x axis, so azimuths turn counter-clockwise seen from the sky (about -axis): a
        beam along -z tilts toward +x at azimuth 0 (BENCHMARK.md's (sin a, 0, -cos a)) and
        toward +y at 90 deg.
        """
        k = int(np.argmin(np.abs(self.axis)))
        e1 = np.eye(3)[k] - self.axis[k] * self.axis
        e1 /= np.linalg.norm(e1)
        return e1, np.cross(e1, self.axis)

    def direction(self, off_axis: float, azimuth: float = 0.0) -> np.ndarray:
        """Unit ray direction tilted by ``off_axis`` (rad) toward azimuth ``azimuth`` (rad)."""
        e1, e2 = self.basis
        tilt = np.cos(azimuth) * e1 + np.sin(azimuth) * e2
        return np.cos(off_axis) * self.axis + np.sin(off_axis) * tilt

    def center_for(self, off_axis: float, azimuth: float = 0.0) -> np.ndarray:
        """Disk centre used at this tilt (see ``pivot_mm``)."""
        if self.pivot_mm is None:
            return self.center_mm
        d = self.direction(off_axis, azimuth)
        n = self.disk_normal
        t = float(np.dot(self.pivot_mm - self.center_mm, n) / np.dot(d, n))
        return self.pivot_mm - t * d

    def source(self, off_axis: float, azimuth: float = 0.0):
        """The engine's ``CollimatedDisk`` for this tilt."""
        from straylight.sources import CollimatedDisk

        return CollimatedDisk(center_mm=self.center_for(off_axis, azimuth), normal=self.disk_normal,
                              direction=self.direction(off_axis, azimuth), radius_mm=float(self.radius_mm),
                              power_w=float(self.power_w), wavelength_nm=self.wavelength_nm)

    def cross_section_mm2(self, off_axis: float, azimuth: float = 0.0) -> float:
        """Beam area normal to the rays: pi R^2 |n . d| (the disk seen along the rays)."""
        d = self.direction(off_axis, azimuth)
        return float(np.pi * self.radius_mm**2 * abs(np.dot(self.disk_normal, d)))

    def irradiance_w_per_mm2(self, off_axis: float, azimuth: float = 0.0) -> float:
        """Irradiance on a plane normal to the rays: P / (pi R^2 |n . d|) (P / (pi R^2 cos a) when the
        disk is normal to ``axis``; the disk is fixed, so a tilted beam spreads its power wider)."""
        return self.power_w / self.cross_section_mm2(off_axis, azimuth)


@dataclass(frozen=True, eq=False)
class Entrance:
    """The instrument's entrance: a disk perpendicular to the beam axis.

    The power crossing it, for a beam that covers it, is ``P (r_e / R)^2`` whatever the
    tilt: the beam's projection along the rays onto the entrance plane is a translated copy
    of the source disk.
    """

    center_mm: np.ndarray
    radius_mm: float
    normal: np.ndarray | None = None

    def __post_init__(self):
        object.__setattr__(self, "center_mm", np.asarray(self.center_mm, dtype=np.float64).reshape(3))
        from straylight.sources import MIN_RADIUS_MM

        if not (np.isfinite(self.radius_mm) and self.radius_mm >= MIN_RADIUS_MM):
            raise ValueError(f"entrance radius_mm must be >= {MIN_RADIUS_MM:g} mm (a disk with a usable area), "
                             f"got {self.radius_mm!r}")
        if self.normal is not None:
            n = np.asarray(self.normal, dtype=np.float64).reshape(3)
            if not np.isfinite(np.linalg.norm(n)) or np.linalg.norm(n) == 0:
                raise ValueError(f"entrance normal must be 3 finite numbers, not all zero, got {self.normal!r}")
            object.__setattr__(self, "normal", n / np.linalg.norm(n))

    def power_w(self, beam: Beam, off_axis: float, azimuth: float = 0.0) -> float:
        """Beam power crossing the entrance disk; ValueError if the beam does not cover it.

        P r_e^2 |n_e . d| / (R^2 |n_s . d|): the entrance's area seen along the rays over the
        beam's (n_e: entrance normal, default the beam axis; n_s: the source disk's normal).
        """
        d = beam.direction(off_axis, azimuth)
        n = beam.disk_normal
        # walk back from the entrance centre along the rays to the source plane
        t = float(np.dot(self.center_mm - beam.center_mm, n) / np.dot(d, n))
        foot = self.center_mm - t * d
        offset = float(np.linalg.norm(foot - beam.center_for(off_axis, azimuth)))
        if offset + self.radius_mm > beam.radius_mm * (1 + 1e-12):
            raise ValueError(
                f"beam (radius_mm {beam.radius_mm:g}) does not cover the entrance (radius_mm {self.radius_mm:g}) "
                f"at {np.degrees(off_axis):g} deg off axis: offset {offset:.3g} mm; use a larger beam"
            )
        n_e = beam.axis if self.normal is None else self.normal
        return beam.power_w * self.radius_mm**2 * abs(float(np.dot(n_e, d))) / (
            beam.radius_mm**2 * abs(float(np.dot(n, d))))


@dataclass(frozen=True, eq=False)
class Setup:
    """What a PST analysis needs: scene, materials, beam, entrance (optional), detector name."""

    scene: object
    materials: dict | None
    beam: Beam
    entrance: Entrance | None
    detector: str
    description: str = ""
    params: dict | None = None
    detector_area_mm2: float | None = None  # None: straylight.detectors.sensitive_area of the part


def resolve_materials(material) -> tuple[str, dict | None]:
    """A material name (preset or file) or a Brdf object -> (tag, {tag: model})."""
    if isinstance(material, str):
        from materials import load_material

        return material, {material: load_material(material)}
    return "coating", {"coating": material}


@lru_cache(maxsize=16)
def _tube_scene(params, tolerance_mm: float):
    """Tessellated tube, untagged; cached because CadQuery takes seconds and scenes are immutable."""
    from geometry.parts.tube import build_tube
    from geometry.tessellate import tessellate_parts

    return tessellate_parts(build_tube(params), tolerance_mm=tolerance_mm)


def _tagged(scene, tag: str):
    """The same triangles with material ``tag`` on every non-detector part (arrays are shared)."""
    from geometry.mesh import Part, Scene

    return Scene(tuple(Part(p.name, p.vertices_mm, p.faces, None if p.role == "detector" else tag, p.role, p.meta)
                       for p in scene.parts))


def tube_setup(material=DEFAULT_MATERIAL, tolerance_mm: float = DEFAULT_TOLERANCE_MM, **params) -> Setup:
    """The built-in tube (``geometry.parts.tube.TubeParams`` keywords override the reference).

    material : preset name, material file path, or a Brdf model, put on every non-detector part
    """
    from geometry.parts.tube import REFERENCE_TUBE

    p = replace(REFERENCE_TUBE, **params) if params else REFERENCE_TUBE
    tag, mats = resolve_materials(material)
    scene = _tagged(_tube_scene(p, float(tolerance_mm)), tag)
    beam, entrance = tube_beam_and_entrance(p)
    params_dict = {f: getattr(p, f) for f in p.names()}
    desc = (f"baffled tube r={p.inner_radius_mm:g} mm, L={p.length_mm:g} mm, {p.vane_count} vanes "
            f"(hole r={p.vane_inner_radius_mm:g} mm), coating {material if isinstance(material, str) else repr(material)}")
    return Setup(scene, mats, beam, entrance, "detector", desc, params_dict)


def tube_beam_and_entrance(p) -> tuple[Beam, Entrance]:
    """The PST beam and entrance of a tube built from ``TubeParams`` ``p``."""
    top = p.length_mm + (p.aperture_stop_thickness_mm if p.aperture_stop_radius_mm is not None else 0.0)
    r_entrance = p.aperture_stop_radius_mm if p.aperture_stop_radius_mm is not None else p.inner_radius_mm
    # only the entrance and the rim (r < outer radius at the top) can send light inside: rays
    # outside it meet the outer wall, whose normal faces away from every other surface
    beam_radius = p.outer_radius_mm
    # the disk slides with the tilt so that it always covers the entrance and the rim
    beam = Beam(center_mm=(0.0, 0.0, top + BEAM_STANDOFF_MM), axis=(0.0, 0.0, -1.0), radius_mm=beam_radius,
                pivot_mm=(0.0, 0.0, top))
    entrance = Entrance(center_mm=(0.0, 0.0, top), radius_mm=r_entrance, normal=(0.0, 0.0, 1.0))
    return beam, entrance
