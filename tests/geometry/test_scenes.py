"""Cached tube scenes: same parameters give the same (read-only) parts; tags are applied."""
import time

import numpy as np
import pytest

from geometry.mesh import GeometryError
from geometry.scenes import reference_scene, tube_scene


def test_reference_scene_tags(reference):
    assert all(p.material == "benchmark_black" and p.role == "surface" for p in reference.parts[:-1])
    assert reference.parts[-1].name == "detector" and reference.parts[-1].role == "detector"
    assert reference_scene(material="z307").part("wall").material == "z307"


def test_identical_parameters_reuse_the_cached_tessellation():
    a = tube_scene(vane_count=3, vane_bevel_deg=20.0, materials={"vane_1": "special"})
    b = tube_scene(vane_count=3, vane_bevel_deg=20.0, materials={"vane_1": "special"})
    assert a.parts[1] is b.parts[1]
    assert a.part("vane_1").material == "special" and a.part("vane_2").material == "benchmark_black"
    with pytest.raises(ValueError):
        a.part("wall").vertices_mm[0, 0] = 1.0  # read-only: nobody can corrupt the cache


def test_unknown_parameter_is_named():
    with pytest.raises(GeometryError, match="vane_cuont"):
        tube_scene(vane_cuont=3)


def test_building_the_default_tube_is_fast():
    """Design studies rebuild the tube many times: build + tessellate (uncached) in well under 2 s
    on an idle core; 6 s here leaves room for a loaded shared machine."""
    from geometry.parts.tube import TubeParams, build_tube
    from geometry.tessellate import tessellate_parts

    tessellate_parts(build_tube(TubeParams(vane_count=2)))  # warm up OCC
    start = time.perf_counter()
    scene = tessellate_parts(build_tube(TubeParams(vane_bevel_deg=np.float64(10.0))))
    assert len(scene.triangles_mm) > 1000
    assert time.perf_counter() - start < 6.0


def test_keyword_overrides_apply_to_given_params():
    from geometry.parts.tube import TubeParams

    scene = tube_scene(params=TubeParams(vane_count=2), vane_inner_radius_mm=30.0, tolerance_mm=0.2)
    assert scene.part_names[:3] == ("wall", "vane_1", "vane_2")
    v = scene.part("vane_2").vertices_mm
    assert np.hypot(v[:, 0], v[:, 1]).min() == pytest.approx(30.0, abs=1e-9)
