"""straylight.intersect.embree_build: the numpy-filled Embree geometry is embreex's TriangleMesh bit for bit,
and anything it cannot check falls back to embreex's own way."""
import numpy as np
import pytest

from straylight.intersect import embree_build
from straylight.intersect.embree import EmbreeIntersector

embreex_scene = pytest.importorskip("embreex.rtcore_scene")


def _triangles(rng, n=5000):
    # scales from 1e-3 to 1e3 mm: float64 -> float32 rounding differs from truncation on most of them
    return rng.normal(size=(n, 3, 3)) * [1.0, 1e3, 1e-3] + rng.normal(size=(n, 1, 3)) * 50.0


def _rays(rng, n=50000):
    o = (rng.normal(size=(n, 3)) * 30.0).astype(np.float32)
    d = rng.normal(size=(n, 3))
    return o, (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)


def test_fast_build_answers_as_embreex_triangle_mesh():
    from embreex.mesh_construction import TriangleMesh

    rng = np.random.default_rng(7)
    tri = _triangles(rng)
    reference = embreex_scene.EmbreeScene()
    TriangleMesh(reference, tri.astype(np.float32))
    ours = EmbreeIntersector(tri)
    assert not hasattr(ours, "_mesh")  # the fast path was taken
    o, d = _rays(rng)
    a, b = reference.run(o, d, output=1), ours._scene.run(o, d, output=1)
    assert set(a) == set(b) and all(np.array_equal(a[k], b[k]) for k in a)
    assert 0.2 < np.mean(a["primID"] >= 0) < 1.0  # hits and misses both tested
    tmax = np.full(len(o), 25.0, dtype=np.float32)
    assert np.array_equal(reference.run(o, d, dists=tmax.copy(), query="OCCLUDED"),
                          ours._scene.run(o, d, dists=tmax.copy(), query="OCCLUDED"))


def test_layout_checks_refuse_a_scene_they_cannot_verify():
    from embreex.rtcore import EmbreeDevice

    tri = _triangles(np.random.default_rng(1), 10)
    device = EmbreeDevice()
    scene = embreex_scene.EmbreeScene(device)
    assert not embree_build.add_triangles(scene, EmbreeDevice(), tri)  # not this scene's device
    assert not embree_build.commit(scene, EmbreeDevice())
    assert embree_build.add_triangles(scene, device, tri)
    assert embree_build.commit(scene, device) and scene.is_committed == 1
    assert not embree_build.add_triangles(scene, device, tri)  # committed: no more geometry


def test_fallback_to_triangle_mesh_gives_the_same_hits(monkeypatch):
    rng = np.random.default_rng(3)
    tri = _triangles(rng, 2000)
    fast = EmbreeIntersector(tri)
    monkeypatch.setattr(embree_build, "add_triangles", lambda *a: False)
    slow = EmbreeIntersector(tri)
    assert hasattr(slow, "_mesh") and not hasattr(fast, "_mesh")
    o, d = _rays(rng, 20000)
    ta, da = fast.intersect(o.astype(float), d.astype(float))
    tb, db = slow.intersect(o.astype(float), d.astype(float))
    assert np.array_equal(ta, tb) and np.array_equal(da, db)
    assert np.array_equal(fast.occluded(o, d, np.full(len(o), 10.0)), slow.occluded(o, d, np.full(len(o), 10.0)))
