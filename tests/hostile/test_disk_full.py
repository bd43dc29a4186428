"""Hostile input: a full cache disk failed every command with "[Errno 28] No space left on device" without
naming the cache. The one-line error now names the folder and what to do."""
from __future__ import annotations

import errno

import pytest

import straylight.scene
from straylight.cli.main import main


def _full(filename=None):
    def raiser(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device", *( [filename] if filename else []))
    return raiser


@pytest.mark.parametrize("in_cache", [True, False])
def test_full_cache_disk_names_the_cache(tmp_path, capsys, monkeypatch, scene, in_cache):
    cache = tmp_path / "cache"
    monkeypatch.setenv("STRAYLIGHT_CACHE_DIR", str(cache))
    monkeypatch.setattr(straylight.scene, "load_scene", _full(str(cache / "numba" / "k.nbi") if in_cache else None))
    assert main(["trace", str(scene), "--rays", "1000", "--json", str(tmp_path / "o.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "no space left on the disk of the cache folder" in err
    assert str(cache) in err and "STRAYLIGHT_CACHE_DIR" in err


def test_full_output_disk_names_the_file(tmp_path, capsys, monkeypatch, scene):
    out = tmp_path / "results" / "o.json"
    monkeypatch.setattr(straylight.scene, "load_scene", _full(str(out)))
    assert main(["trace", str(scene), "--rays", "1000", "--json", str(tmp_path / "o.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert f"no space left on the disk holding {out}" in err
