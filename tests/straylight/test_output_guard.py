"""Outputs checked before the work, and never overwriting what the user wrote.

``trace --json`` onto a folder or into a folder it cannot write fails at once, before the scene is
even read (the scene given here does not exist, so an error about it would mean the output was
checked too late); ``geometry build -o``, ``geometry scene -o`` and ``design vanes --out`` refuse to
replace a file the user edited or wrote, unless ``--force``, and replace their own unchanged
files freely."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from atomicio.guard import MANIFEST, OverwriteError, check_overwrite, record_outputs
from straylight.cli.main import main

DATA = Path(__file__).resolve().parents[1] / "data"


def test_trace_json_onto_a_folder_fails_before_the_scene_is_read(tmp_path, capsys):
    assert main(["trace", str(tmp_path / "missing.toml"), "--rays", "1000", "--json", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--json output is a folder" in err[0]


@pytest.fixture
def open_tmp():
    """A folder every user can reach (pytest's tmp_path sits in a folder of mode 0700)."""
    import tempfile

    path = Path(tempfile.mkdtemp(prefix="straylight-ro-", dir="/tmp" if os.path.isdir("/tmp") else None))
    os.chmod(path, 0o755)
    yield path
    shutil.rmtree(path, ignore_errors=True)


def test_trace_json_into_a_read_only_folder_fails_at_once(open_tmp, as_nobody):
    """As another user where the tests run as root (root writes anywhere): a folder the user cannot write."""
    tmp_path = open_tmp
    folder = tmp_path / "ro"
    folder.mkdir()
    os.chmod(folder, 0o555)
    cmd = [sys.executable, "-m", "straylight.cli.main", "trace", str(tmp_path / "missing.toml"), "--rays", "1000",
           "--json", str(folder / "out.json")]
    if os.geteuid() == 0:
        cmd = as_nobody(cmd, "no folder is read-only to root")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path), "HOME": str(folder),
           "STRAYLIGHT_CACHE": "off", "NUMBA_CACHE_DIR": str(folder)}
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=60, env=env, cwd=str(folder))
    err = res.stderr.strip().splitlines()
    assert res.returncode == 2 and len(err) == 1, res.stderr
    assert str(folder) in err[0] and "cannot write the --json output" in err[0]


def test_overwrite_guard_units(tmp_path):
    (tmp_path / "scene.toml").write_text("mine\n")
    with pytest.raises(OverwriteError, match="was not written by straylight"):
        check_overwrite(tmp_path, names=["scene.toml"])
    check_overwrite(tmp_path, names=["scene.toml"], force=True)
    record_outputs(tmp_path, names=["scene.toml"])
    check_overwrite(tmp_path, names=["scene.toml"])  # unchanged since recorded: may be replaced
    (tmp_path / "scene.toml").write_text("mine, edited\n")
    with pytest.raises(OverwriteError, match="changed since straylight wrote it"):
        check_overwrite(tmp_path, patterns=["*.toml"])
    (tmp_path / "notes.txt").write_text("not an output\n")
    check_overwrite(tmp_path, names=["other.toml"], patterns=["*.stl"])  # nothing it writes is there


def test_geometry_build_keeps_a_hand_edited_scene(tmp_path, capsys):
    out = tmp_path / "b"
    args = ["geometry", "build", "tube", "--vanes", "1", "--no-step", "--tolerance-mm", "0.5", "-o", str(out)]
    assert main(args) == 0
    assert (out / MANIFEST).is_file()
    edited = (out / "scene.toml").read_text() + "# my note\n"
    (out / "scene.toml").write_text(edited)
    capsys.readouterr()
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{out / 'scene.toml'}: was changed" in err[0] and "--force" in err[0]
    assert (out / "scene.toml").read_text() == edited


def test_geometry_scene_never_overwrites_without_force(tmp_path, capsys):
    step = tmp_path / "parts.step"
    shutil.copy(DATA / "cad" / "gmsh_parts.step", step)
    scene = tmp_path / "scene.toml"
    scene.write_text("# written by hand\n")
    assert main(["geometry", "scene", str(step), "-o", str(scene), "--tolerance-mm", "0.5"]) == 2
    err = capsys.readouterr().err
    assert "this command did not write it" in err and "--force" in err  # the output rule of every command
    assert scene.read_text() == "# written by hand\n"
    assert main(["geometry", "scene", str(step), "-o", str(tmp_path)]) == 2
    assert "is a folder" in capsys.readouterr().err


def test_design_vanes_refuses_before_any_work(tmp_path, capsys):
    (tmp_path / "scene.toml").write_text("# the user's own scene\n")
    code = main(["design", "vanes", "--tube-radius-mm", "50", "--tube-length-mm", "300", "--stop-radius-mm", "35",
                 "--field-deg", "0", "--exclusion-deg", "20", "--rays", "1000", "--out", str(tmp_path)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "scene.toml: was not written by straylight" in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.toml"]
