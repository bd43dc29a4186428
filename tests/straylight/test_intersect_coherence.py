"""Coherent ray order for embree (straylight.intersect.coherence): a permutation grouped by origin
cell, and the same answers as the plain casts, alone and inside a whole trace."""
import math

import numpy as np

from straylight.execution import Execution
from straylight.intersect import coherence, embree
from straylight.intersect.coherence import coherent_float32, scatter_back
from straylight.intersect.embree import EmbreeIntersector


def _soup(n=3000, seed=0):
    rng = np.random.default_rng(seed)
    centre = rng.uniform(-50, 50, size=(n, 1, 3))
    return centre + rng.normal(scale=3.0, size=(n, 3, 3))


def _rays(n, seed=1):
    rng = np.random.default_rng(seed)
    o = rng.uniform(-60, 60, size=(n, 3))
    d = rng.normal(size=(n, 3))
    return o, d / np.linalg.norm(d, axis=1, keepdims=True)


def _morton_cell(o, bits):
    lo, hi = o.min(axis=0), o.max(axis=0)
    q = np.clip(((o - lo) * ((1 << bits) / (hi - lo))).astype(np.int64), 0, (1 << bits) - 1)
    key = np.zeros(len(o), np.int64)
    for b in range(bits):  # interleave x, y, z bits: x lowest
        for axis in range(3):
            key |= ((q[:, axis] >> b) & 1) << (3 * b + axis)
    return key


def test_order_is_a_stable_permutation_by_morton_cell():
    o, d = _rays(5000)
    t = np.linspace(1.0, 2.0, len(o))
    o32, d32, t32, perm = coherent_float32(o, d, t, 3)
    assert np.array_equal(np.sort(perm), np.arange(len(o)))
    assert np.array_equal(o32, o[perm].astype(np.float32))
    assert np.array_equal(d32, d[perm].astype(np.float32))
    assert np.array_equal(t32, t[perm].astype(np.float32))
    key = _morton_cell(o, 3)[perm]  # an independent Morton key
    assert np.all(np.diff(key) >= 0)
    same_cell = np.diff(key) == 0
    assert np.all(np.diff(perm)[same_cell] > 0)  # stable within a cell
    assert np.array_equal(scatter_back(np.arange(len(o))[perm], perm), np.arange(len(o)))


def test_degenerate_origins_do_not_break_the_order():
    o = np.zeros((100, 3))
    o[7] = np.nan
    o[9, 2] = np.inf
    d = np.tile([0.0, 0.0, 1.0], (100, 1))
    _, _, _, perm = coherent_float32(o, d, np.zeros(0), 4)
    assert np.array_equal(np.sort(perm), np.arange(100))


def test_coherent_casts_answer_as_the_plain_ones(monkeypatch):
    tri = _soup()
    plain = EmbreeIntersector(tri)
    assert plain._min_rays == np.inf  # a small scene casts in the caller's order
    monkeypatch.setattr(embree, "MIN_TRIANGLES", 0)
    monkeypatch.setattr(embree, "MIN_RAYS", 16)
    ordered = EmbreeIntersector(tri)
    o, d = _rays(20000)
    hit = plain.first_triangle(o, d)
    assert (hit >= 0).sum() > 1000 and (hit < 0).sum() > 1000
    assert np.array_equal(ordered.first_triangle(o, d), hit)
    tmax = np.random.default_rng(2).uniform(0, 80, len(o))
    blocked = plain.occluded(o, d, tmax)
    assert 1000 < blocked.sum() < len(o) - 1000
    assert np.array_equal(ordered.occluded(o, d, tmax), blocked)


def test_trace_with_coherent_casts_is_identical(monkeypatch):
    from geometry.scenes import reference_scene
    from materials import Lambertian
    from straylight.sources import CollimatedDisk
    from straylight.trace import TraceOptions, trace

    scene = reference_scene(tolerance_mm=0.05)
    a = math.radians(20.0)
    src = CollimatedDisk([0, 0, 310], [0, 0, -1], [math.sin(a), 0, -math.cos(a)], 60.0)
    mats = {scene.parts[0].material: Lambertian(0.05)}
    opts = TraceOptions(batch_rays=10_000)
    base = trace(scene, src, 20_000, 4, materials=mats, options=opts,
                 execution=Execution(intersector=EmbreeIntersector(scene.triangles_mm)))
    monkeypatch.setattr(embree, "MIN_TRIANGLES", 0)
    monkeypatch.setattr(embree, "MIN_RAYS", 64)
    isect = EmbreeIntersector(scene.triangles_mm)
    assert isect._min_rays == 64
    res = trace(scene, src, 20_000, 4, materials=mats, options=opts, execution=Execution(intersector=isect))
    assert res.to_json_dict() == base.to_json_dict()
    assert res.segments == base.segments and res.shadow_rays == base.shadow_rays
    assert coherence.CELL_BITS >= 1
