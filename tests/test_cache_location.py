"""Caches under the user's cache folder: with a read-only install and a read-only
HOME, ``straylight material eval`` (which compiles a kernel) works, its compiled code cached in a
private temporary folder; a temp folder another user could write is never used; ``NUMBA_CACHE_DIR``
set by the user is kept; a tessellation cache entry changed after it was written is never served."""
from __future__ import annotations

import json
import os
import shutil
import stat
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from atomicio import cache_dirs

MODEL = {"name": "m", "wavelength_nm": 532.0, "components": [
    {"type": "lambertian", "rd": 0.03}, {"type": "k_correlation", "sigma_nm": 3.0, "lc_um": 40.0, "s": 2.4, "n": 1.52}]}


@pytest.fixture
def shared_tmp():
    """A sticky world-writable folder like /tmp (pytest's tmp_path is private to root)."""
    path = Path(tempfile.mkdtemp(prefix="straylight-cachetest-", dir="/tmp" if os.path.isdir("/tmp") else None))
    os.chmod(path, 0o1777)
    yield path
    shutil.rmtree(path, ignore_errors=True)


def test_read_only_install_and_home_still_trace_materials(shared_tmp, as_nobody):
    """Run as another user where the tests run as root (then the checkout is a read-only install for
    it, and HOME does not exist); else with HOME a read-only folder."""
    model = shared_tmp / "model.json"
    model.write_text(json.dumps(MODEL))
    os.chmod(model, 0o644)
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "XDG_CACHE_HOME", "STRAYLIGHT_CACHE_DIR")}
    env.update(PYTHONPATH=os.pathsep.join(p for p in sys.path if p), TMPDIR=str(shared_tmp))
    cmd = [sys.executable, "-m", "straylight.cli.main", "material", "eval", str(model), "--theta-i-deg", "30",
           "--theta-r-deg", "10", "--polarization", "s", "--json", str(shared_tmp / "out.json")]
    if os.geteuid() == 0:
        cmd = as_nobody(cmd, "nothing is read-only to root")
        env["HOME"] = "/nonexistent"
        uid = 65534
    else:
        home = shared_tmp / "home"
        home.mkdir(mode=0o555)
        env["HOME"] = str(home)
        uid = os.getuid()
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=180, env=env, cwd=str(shared_tmp))
    assert res.returncode == 0, res.stderr
    assert json.loads((shared_tmp / "out.json").read_text())["brdf_per_sr"][0] > 0
    private = shared_tmp / f"straylight-cache-{uid}"
    assert stat.S_IMODE(private.stat().st_mode) == 0o700 and private.stat().st_uid == uid
    assert list((private / "numba").rglob("*.nbi")), "no compiled kernel was cached in the private folder"


def test_temp_folder_another_user_could_write_is_not_used(tmp_path, monkeypatch):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    planted = tmp_path / f"straylight-cache-{os.getuid()}"
    planted.mkdir()
    os.chmod(planted, 0o777)  # as another user would leave it, to plant cached code
    chosen = cache_dirs._private_temp()
    assert chosen != planted and chosen.parent == tmp_path and stat.S_IMODE(chosen.stat().st_mode) == 0o700
    os.chmod(planted, 0o700)
    assert cache_dirs._private_temp() == planted


def test_user_choices_are_kept(tmp_path, monkeypatch):
    """NUMBA_CACHE_DIR set by the user (in a fresh interpreter: numba reads it once) and STRAYLIGHT_CACHE_DIR."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "mine"), "PYTHONPATH": os.pathsep.join(sys.path)}
    out = subprocess.run([sys.executable, "-c", "import straylight, numba; print(numba.config.CACHE_DIR)"],
                         capture_output=True, text=True, env=env, timeout=120)
    assert out.stdout.strip() == str(tmp_path / "mine"), out.stderr
    monkeypatch.setenv("STRAYLIGHT_CACHE_DIR", str(tmp_path / "c"))
    assert cache_dirs.cache_dir("tessellation") == tmp_path / "c" / "tessellation"


def test_changed_tessellation_entry_is_never_served(tmp_path):
    import numpy as np

    from geometry import cad_cache
    from geometry.mesh import Part
    from geometry.tessellate import TessellationReport

    report = TessellationReport(**{f: 0 for f in TessellationReport.__dataclass_fields__})
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    part = Part("s", v, f, None, "surface", {"tessellation": report, "brep_face": np.zeros(4)})
    entry = tmp_path / "e.npz"
    cad_cache.store(entry, [("s", "solid", None, part)])
    assert np.array_equal(cad_cache.load(entry)[0][3].vertices_mm, v)
    with np.load(entry) as data:  # one vertex moved by 1 mm, the zip itself valid (its CRC recomputed)
        arrays = {k: data[k] for k in data.files}
    arrays["v0"] = arrays["v0"] + np.array([0, 0, 1.0])
    np.savez(entry, **arrays)
    with pytest.warns(cad_cache.CacheWarning, match="checksum mismatch"):
        assert cad_cache.load(entry) is None
