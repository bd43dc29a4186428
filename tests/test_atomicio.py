"""The project's one atomic writer (atomicio): umask, durability order, atomicity."""
import json
import os
import stat

import numpy as np
import pytest

import atomicio


@pytest.fixture
def umask_022():
    old = os.umask(0o022)
    try:
        yield
    finally:
        os.umask(old)


def _mode(path):
    return stat.S_IMODE(os.stat(path).st_mode)


def test_new_file_gets_the_users_umask(tmp_path, umask_022):
    # what open(path, "w") gives any other program under umask 022: 0o666 & ~0o022
    expected = 0o666 & ~0o022
    for write in (lambda p: atomicio.write_text(p, "x"), lambda p: atomicio.write_bytes(p, b"x"),
                  lambda p: atomicio.write_json(p, {"a": 1}), lambda p: atomicio.append_text(p, "x")):
        path = tmp_path / f"f{len(list(tmp_path.iterdir()))}.txt"
        write(path)
        assert _mode(path) == expected == 0o644
    with open(tmp_path / "plain.txt", "w") as fh:  # same as a plain open()
        fh.write("x")
    assert _mode(tmp_path / "plain.txt") == 0o644


def test_other_umask_and_existing_mode_kept(tmp_path):
    old = os.umask(0o077)
    try:
        atomicio.write_text(tmp_path / "a.txt", "x")
        assert _mode(tmp_path / "a.txt") == 0o600
        os.chmod(tmp_path / "a.txt", 0o640)
        atomicio.write_text(tmp_path / "a.txt", "y")  # replacing keeps the file's own mode
        assert _mode(tmp_path / "a.txt") == 0o640
    finally:
        os.umask(old)


def test_fsync_file_then_directory_after_rename(tmp_path, monkeypatch):
    path = tmp_path / "out.json"
    calls = []
    real_fsync, real_replace = os.fsync, os.replace

    def fake_fsync(fd):
        kind = "dir" if stat.S_ISDIR(os.fstat(fd).st_mode) else "file"
        calls.append((kind, path.exists()))
        real_fsync(fd)

    def fake_replace(src, dst):
        calls.append(("replace", None))
        real_replace(src, dst)

    monkeypatch.setattr(os, "fsync", fake_fsync)
    monkeypatch.setattr(os, "replace", fake_replace)
    atomicio.write_json(path, {"a": 1})
    # the file's data are on disk before the rename, the folder entry after it
    assert calls == [("file", False), ("replace", None), ("dir", True)]
    calls.clear()
    atomicio.write_text(path, "x", fsync=False)
    assert calls == [("replace", None)]


def test_failed_write_leaves_old_file_and_no_temp(tmp_path):
    path = tmp_path / "keep.txt"
    atomicio.write_text(path, "old")
    with pytest.raises(RuntimeError):
        with atomicio.atomic_open(path) as fh:
            fh.write("half")
            raise RuntimeError("boom")
    assert path.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.txt"]


def test_write_json_is_strict_and_numpy_clean(tmp_path):
    path = tmp_path / "r.json"
    atomicio.write_json(path, {"x": np.float64(1.5), "n": np.int64(3), "v": np.array([1.0, np.nan]),
                               "t": (1, 2), "inf": float("inf"), "ok": np.bool_(True)})
    text = path.read_text()
    assert text.endswith("\n") and "NaN" not in text and "Infinity" not in text
    assert json.loads(text) == {"x": 1.5, "n": 3, "v": [1.0, None], "t": [1, 2], "inf": None, "ok": True}
    assert atomicio.json_safe({"p": tmp_path, "o": complex(1, 2)}) == {"p": str(tmp_path), "o": "(1+2j)"}


def test_file_sha256_is_hashlib_over_the_whole_file_in_blocks(tmp_path):
    """atomicio.digest.file_sha256 reads in blocks: the digest is hashlib's over all the bytes (a file
    of 2.5 blocks, and an empty one: the known SHA-256 of no bytes, FIPS 180-4 test vector)."""
    import hashlib

    from atomicio.digest import BLOCK_BYTES, file_matches, file_sha256

    data = np.random.default_rng(0).integers(0, 256, int(2.5 * BLOCK_BYTES), dtype=np.uint8).tobytes()
    (tmp_path / "big.bin").write_bytes(data)
    assert file_sha256(tmp_path / "big.bin") == hashlib.sha256(data).hexdigest()
    (tmp_path / "empty").write_bytes(b"")
    assert file_sha256(tmp_path / "empty") == "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855"
    assert file_matches(tmp_path / "big.bin", hashlib.sha256(data).hexdigest())
    (tmp_path / "big.bin").write_bytes(data[:-1] + bytes([data[-1] ^ 1]))  # one bit changed
    assert not file_matches(tmp_path / "big.bin", hashlib.sha256(data).hexdigest())


def test_guard_and_tessellation_cache_hash_files_with_the_one_helper(tmp_path, monkeypatch):
    """The overwrite guard's manifest and the tessellation cache's key both come from
    atomicio.digest.file_sha256: a stand-in for it changes both."""
    import atomicio.digest
    import atomicio.guard
    import geometry.cad_cache

    assert atomicio.guard.file_sha256 is atomicio.digest.file_sha256
    assert geometry.cad_cache.file_sha256 is atomicio.digest.file_sha256
    (tmp_path / "scene.toml").write_text("x")
    atomicio.guard.record_outputs(tmp_path, names=["scene.toml"])
    manifest = json.loads((tmp_path / atomicio.guard.MANIFEST).read_text())
    assert manifest["files"]["scene.toml"] == atomicio.digest.file_sha256(tmp_path / "scene.toml")
    monkeypatch.setenv("STRAYLIGHT_CACHE_DIR", str(tmp_path / "cache"))
    entry = geometry.cad_cache.entry_path(tmp_path / "scene.toml", tolerance_mm=0.1, angular_tolerance_deg=5.0,
                                          mode="whole")
    monkeypatch.setattr(geometry.cad_cache, "file_sha256", lambda path: "0" * 64)
    assert geometry.cad_cache.entry_path(tmp_path / "scene.toml", tolerance_mm=0.1, angular_tolerance_deg=5.0,
                                         mode="whole") != entry


def _doc():
    """A result document like the project's: nested, numpy numbers, a tuple, NaN and infinities."""
    return {"rays": 1000, "seed": 1, "emitted_w": np.float64(1.0), "angles_deg": (0.0, 5.5),
            "detectors": {"fp": {"power_w": 1.2e-6, "stderr_w": float("nan")}},
            "points": [{"pst": 3.4e-5, "pst_stderr": float("inf")}, {"pst": -float("inf"), "name": "é"}],
            "flags": [True, False, None], "empty": {}}


def test_write_json_keeps_the_bytes_of_each_former_hand_written_writer(tmp_path):
    """The writers moved onto atomicio.write_json keep their files' bytes: each option set against the
    standard library's json.dumps call the module used before (the independent reference)."""
    from event_model import NumpyEncoder

    doc = _doc()
    plain = {k: (list(v) if isinstance(v, tuple) else v) for k, v in doc.items()} | {"emitted_w": 1.0}
    # strict JSON (CONTRACTS 1): the same bytes with every non-finite number as null
    plain["detectors"] = {"fp": {"power_w": 1.2e-6, "stderr_w": None}}
    plain["points"] = [{"pst": 3.4e-5, "pst_stderr": None}, {"pst": None, "name": "é"}]
    cases = [  # (before, after); allow_nan=True (the former non-strict writers) is strict now too
        (json.dumps(plain, indent=2), dict(allow_nan=True, final_newline=False)),  # pst/critical/paths/sweep, geometry --json
        (json.dumps(plain, indent=2) + "\n", dict()),  # trace, material, twin, ghosts, telescope
        (json.dumps(plain, indent=1) + "\n", dict(indent=1)),  # checkpoint run.json
        (json.dumps(plain) + "\n", dict(indent=None)),  # checkpoint point files
    ]
    for i, (before, kwargs) in enumerate(cases):
        atomicio.write_json(tmp_path / f"{i}.json", doc, **kwargs)
        assert (tmp_path / f"{i}.json").read_bytes() == before.encode("utf-8"), kwargs
    files = {"b.txt": "ab" * 32, "a.txt": "cd" * 32}  # the overwrite guard's manifest: sorted, indent 1
    atomicio.write_json(tmp_path / "m.json", {"files": files}, indent=1, sort_keys=True)
    assert (tmp_path / "m.json").read_text() == json.dumps({"files": files}, indent=1, sort_keys=True) + "\n"
    params = {"tube_radius_mm": 50.0, "n_vanes": 7}  # geometry/parts/assembly.py params.json: no final newline
    atomicio.write_json(tmp_path / "p.json", params, final_newline=False)
    assert (tmp_path / "p.json").read_text() == json.dumps(params, indent=2)
    for _ in range(2):  # the bluesky document log: one [name, doc] per line, event-model's encoder
        atomicio.append_json_line(tmp_path / "log.jsonl", ["event", {"x": np.float64(0.5), "v": np.arange(2)}],
                                  encoder=NumpyEncoder)
    line = json.dumps(["event", {"x": np.float64(0.5), "v": np.arange(2)}], cls=NumpyEncoder) + "\n"
    assert (tmp_path / "log.jsonl").read_text() == 2 * line
    atomicio.append_json_line(tmp_path / "nan.jsonl", ["event", {"x": np.float64("nan"), "v": np.array([np.inf])}],
                              encoder=NumpyEncoder)
    assert (tmp_path / "nan.jsonl").read_text() == '["event", {"x": null, "v": [null]}]\n'


def test_append_text_appends_whole_lines_durably(tmp_path, monkeypatch):
    synced = []
    real_fsync = os.fsync
    monkeypatch.setattr(os, "fsync", lambda fd: (synced.append(fd), real_fsync(fd)))
    path = tmp_path / "new" / "rows.csv"  # the folder is created
    atomicio.append_text(path, "a,b\n")
    atomicio.append_text(path, "1,2\n3,4\n")
    atomicio.append_text(path, "5,6\n", fsync=False)
    assert path.read_text() == "a,b\n1,2\n3,4\n5,6\n" and len(synced) == 2
