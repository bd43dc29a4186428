"""The tessellation cache: keyed by file content + tolerance (+ code), written atomically, never stale."""
import json
from pathlib import Path

import numpy as np
import pytest

from geometry import cad_cache
from geometry.io import load_cad_parts, load_part

DATA = Path(__file__).resolve().parents[1] / "data" / "cad"


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv(cad_cache.ENV_SWITCH, "on")
    monkeypatch.setenv(cad_cache.ENV_DIR, str(tmp_path / "cache"))
    return tmp_path / "cache" / "tessellation"


def test_second_load_comes_from_the_cache_and_is_identical(cache, tmp_path):
    step = tmp_path / "bench.step"
    step.write_bytes((DATA / "ocp_bench_m.step").read_bytes())
    cold = load_cad_parts(step, name="b", tolerance_mm=0.1, solids={"detector": {"role": "detector"}})
    entries = list(cache.glob("*.npz"))
    assert len(entries) == 1 and not any(name.startswith(".") for name in (p.name for p in cache.iterdir()))
    warm = load_cad_parts(step, name="b", tolerance_mm=0.1, solids={"detector": {"role": "detector"}})
    assert all("cache" not in p.meta for p in cold) and all(p.meta["cache"] == str(entries[0]) for p in warm)
    for a, b in zip(cold, warm):
        assert (a.name, a.role, a.material) == (b.name, b.role, b.material)
        assert np.array_equal(a.vertices_mm, b.vertices_mm) and np.array_equal(a.faces, b.faces)
        assert a.meta["tessellation"] == b.meta["tessellation"]
    # the whole-file part (no split) is a separate entry
    load_part(step, tolerance_mm=0.1)
    assert len(list(cache.glob("*.npz"))) == 2


def test_key_changes_with_tolerance_content_and_code(cache, tmp_path, monkeypatch):
    step = tmp_path / "a.step"
    step.write_bytes((DATA / "cq_features.step").read_bytes())
    key = dict(tolerance_mm=0.1, angular_tolerance_deg=10.0, mode="solids")
    first = cad_cache.entry_path(step, **key)
    assert cad_cache.entry_path(step, **dict(key, tolerance_mm=0.05)) != first
    assert cad_cache.entry_path(step, **dict(key, mode="whole")) != first
    step.write_bytes(step.read_bytes() + b"\n")  # any edit of the file
    assert cad_cache.entry_path(step, **key) != first
    step.write_bytes((DATA / "cq_features.step").read_bytes())
    assert cad_cache.entry_path(step, **key) == first
    monkeypatch.setattr(cad_cache, "code_version", lambda: "another")
    assert cad_cache.entry_path(step, **key) != first


def _rewrite_entry(entry, **changes):
    """The entry with some arrays replaced (``meta`` as a dict), written back as a valid npz."""
    with np.load(entry) as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(str(arrays["meta"]))
    for key, value in changes.items():
        if key == "meta":
            value(meta)
        else:
            arrays[key] = value
    arrays["meta"] = np.array(json.dumps(meta))
    np.savez(entry, **arrays)


@pytest.mark.parametrize("damage", ["garbage", "truncated", "face index", "tags length", "no watertight flag"])
def test_damaged_entry_is_reported_and_rewritten(cache, tmp_path, damage):
    step = tmp_path / "g.step"
    step.write_bytes((DATA / "gmsh_parts.step").read_bytes())
    cold = load_cad_parts(step, tolerance_mm=0.2)
    (entry,) = cache.glob("*.npz")
    good = entry.read_bytes()
    if damage == "garbage":
        entry.write_bytes(b"not an npz")
    elif damage == "truncated":
        entry.write_bytes(good[: len(good) // 2])
    elif damage == "face index":
        _rewrite_entry(entry, f0=np.full((4, 3), 10**6, dtype=np.int32))
    elif damage == "tags length":
        _rewrite_entry(entry, b0=np.zeros(3, dtype=np.int32))
    else:
        _rewrite_entry(entry, meta=lambda m: m["solids"][0].pop("watertight"))
    with pytest.warns(cad_cache.CacheWarning, match=r"g-.*\.npz: damaged or incompatible tessellation cache entry"):
        again = load_cad_parts(step, tolerance_mm=0.2)
    assert all("cache" not in p.meta for p in again)
    assert [p.n_triangles for p in again] == [p.n_triangles for p in cold]
    rewritten = cad_cache.load(entry)
    assert [name for name, _, _, _ in rewritten] == [p.meta["solid"] for p in cold]
    assert all(np.array_equal(part.faces, p.faces) and np.array_equal(part.vertices_mm, p.vertices_mm)
               for (_, _, _, part), p in zip(rewritten, cold))


def test_cached_entry_keeps_the_checks_of_the_cold_run(cache, tmp_path):
    """Tags, chord-error reports and watertightness come back from the entry, equal to a fresh check."""
    step = tmp_path / "bench.step"
    step.write_bytes((DATA / "ocp_bench_m.step").read_bytes())
    cold = load_cad_parts(step, name="b", tolerance_mm=0.1)
    warm = load_cad_parts(step, name="b", tolerance_mm=0.1)
    assert all("cache" in p.meta for p in warm)
    for a, b in zip(cold, warm):
        assert a.meta["watertight"] is b.meta["watertight"] is b.is_watertight
        assert np.array_equal(a.meta["brep_face"], b.meta["brep_face"])
        assert (a.meta["kind"], a.meta["solid"], a.meta["label"]) == (b.meta["kind"], b.meta["solid"], b.meta["label"])
    assert any(p.meta["watertight"] for p in warm)


def test_cold_and_cached_scene_trace_the_same_numbers(cache, cad_bench_scene):
    """A scene file on a STEP assembly: the cached load traces bit-identically to the cold one."""
    import warnings

    from straylight.scene import load_scene

    toml = cad_bench_scene
    results = []
    for _ in range(2):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            rs = load_scene(toml)
        results.append((rs, rs.trace(4000, seed=5)))
    (cold, a), (warm, b) = results
    assert all("cache" not in p.meta for p in cold.scene.parts) and all("cache" in p.meta for p in warm.scene.parts)
    assert np.array_equal(cold.scene.triangles_mm, warm.scene.triangles_mm)
    assert np.array_equal(cold.scene.triangle_part, warm.scene.triangle_part)
    assert [(p.name, p.role, p.material) for p in cold.scene.parts] == [(p.name, p.role, p.material)
                                                                         for p in warm.scene.parts]
    assert cold.warnings == warm.warnings
    assert a.detectors["cad/detector"].power_w == b.detectors["cad/detector"].power_w > 0
    assert a.ledger == b.ledger




def test_disabled_and_relocated(tmp_path, monkeypatch):
    monkeypatch.setenv(cad_cache.ENV_SWITCH, "off")
    assert not cad_cache.enabled()
    monkeypatch.setenv(cad_cache.ENV_SWITCH, "on")
    monkeypatch.setenv(cad_cache.ENV_DIR, str(tmp_path / "x"))
    assert cad_cache.enabled() and cad_cache.cache_dir() == tmp_path / "x" / "tessellation"
    monkeypatch.delenv(cad_cache.ENV_DIR)
    assert cad_cache.cache_dir().name == "tessellation" and "straylight" in str(cad_cache.cache_dir())
