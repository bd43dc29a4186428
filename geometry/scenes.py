"""Ready-made scenes: the BENCHMARK.md tube, parametric tubes, the reflectometer.

Tube tessellations are cached (``functools.lru_cache`` keyed by the frozen
:class:`geometry.parts.tube.TubeParams`, the tolerances and the material tags), since
baffle studies rebuild the same tube many times. Cached parts hold read-only arrays, so a
caller cannot corrupt the cache; every call returns a new :class:`Scene` of the same parts.
"""
from __future__ import annotations

from dataclasses import replace
from functools import lru_cache

from geometry.mesh import GeometryError, Part, Scene
from geometry.parts.reflectometer import ReflectometerParams, build_reflectometer
from geometry.parts.tube import REFERENCE_TUBE, TubeParams, build_tube
from geometry.tessellate import DEFAULT_ANGULAR_TOLERANCE_DEG, DEFAULT_TOLERANCE_MM, tessellate_parts

BENCHMARK_MATERIAL = "benchmark_black"


def _frozen(scene: Scene) -> Scene:
    for part in scene.parts:
        part.vertices_mm.flags.writeable = False
        part.faces.flags.writeable = False
        if "brep_face" in part.meta:
            part.meta["brep_face"].flags.writeable = False
    return scene


@lru_cache(maxsize=64)
def _tube_parts(params: TubeParams, tolerance_mm: float, angular_tolerance_deg: float, material: str | None,
                materials: tuple[tuple[str, str], ...]) -> tuple[Part, ...]:
    scene = tessellate_parts(build_tube(params), tolerance_mm=tolerance_mm,
                             angular_tolerance_deg=angular_tolerance_deg, material=material,
                             materials=dict(materials))
    return _frozen(scene).parts


def tube_scene(*, tolerance_mm: float = DEFAULT_TOLERANCE_MM,
               angular_tolerance_deg: float = DEFAULT_ANGULAR_TOLERANCE_DEG, material: str | None = BENCHMARK_MATERIAL,
               materials: dict | None = None, **params) -> Scene:
    """Tessellated baffled tube (:func:`geometry.parts.tube.build_tube`), cached.

    Parameters
    ----------
    tolerance_mm, angular_tolerance_deg : tessellation tolerances (see ``geometry.tessellate``)
    material : material name of every non-detector part; materials : {part name: material name} overrides
    **params : fields of :class:`TubeParams` (e.g. ``vane_count=5, vane_bevel_deg=30``) overriding
        ``params=TubeParams(...)`` (default: the reference tube)
    """
    tube = params.pop("params", None) or REFERENCE_TUBE
    unknown = set(params) - set(TubeParams.names())
    if unknown:
        raise GeometryError(f"unknown tube parameter(s): {', '.join(sorted(unknown))}; "
                            f"known: {', '.join(TubeParams.names())}")
    if params:
        tube = replace(tube, **params)
    key = tuple(sorted((materials or {}).items()))
    return Scene(_tube_parts(tube, float(tolerance_mm), float(angular_tolerance_deg), material, key))


def reference_scene(tolerance_mm: float = DEFAULT_TOLERANCE_MM, material: str | None = BENCHMARK_MATERIAL) -> Scene:
    """The BENCHMARK.md tube: parts wall, vane_1..vane_7, end_plate (tagged ``material``) and detector
    (role "detector", no material; an open disk r < 35 at z = 0 facing +z)."""
    return tube_scene(tolerance_mm=tolerance_mm, material=material, params=REFERENCE_TUBE)


def reflectometer_scene(theta_i_deg: float, theta_r_deg: float, phi_r_deg: float = 0.0, *,
                        params: ReflectometerParams = ReflectometerParams(), sample_material: str | None = None,
                        black_material: str | None = None, tolerance_mm: float = 0.01,
                        angular_tolerance_deg: float = DEFAULT_ANGULAR_TOLERANCE_DEG) -> Scene:
    """Tessellated reflectometer (:func:`geometry.parts.reflectometer.build_reflectometer`): the sample is
    tagged ``sample_material``, holder, post and slit plate ``black_material``."""
    parts = build_reflectometer(theta_i_deg, theta_r_deg, phi_r_deg, params)
    return tessellate_parts(parts, tolerance_mm=tolerance_mm, angular_tolerance_deg=angular_tolerance_deg,
                            material=black_material, materials={"sample": sample_material})
