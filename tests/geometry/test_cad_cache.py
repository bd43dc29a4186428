"""The tessellation cache: keyed by file content + tolerance (+ code), written atomically, never stale."""
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


def test_damaged_entry_is_a_miss_and_is_rewritten(cache, tmp_path):
    step = tmp_path / "g.step"
    step.write_bytes((DATA / "gmsh_parts.step").read_bytes())
    cold = load_cad_parts(step, tolerance_mm=0.2)
    (entry,) = cache.glob("*.npz")
    entry.write_bytes(b"not an npz")
    again = load_cad_parts(step, tolerance_mm=0.2)
    assert all("cache" not in p.meta for p in again)
    assert [p.n_triangles for p in again] == [p.n_triangles for p in cold]
    assert cad_cache.load(entry) is not None  # rewritten


def test_disabled_and_relocated(tmp_path, monkeypatch):
    monkeypatch.setenv(cad_cache.ENV_SWITCH, "off")
    assert not cad_cache.enabled()
    monkeypatch.setenv(cad_cache.ENV_SWITCH, "on")
    monkeypatch.setenv(cad_cache.ENV_DIR, str(tmp_path / "x"))
    assert cad_cache.enabled() and cad_cache.cache_dir() == tmp_path / "x" / "tessellation"
    monkeypatch.delenv(cad_cache.ENV_DIR)
    assert cad_cache.cache_dir().name == "tessellation" and "straylight" in str(cad_cache.cache_dir())
