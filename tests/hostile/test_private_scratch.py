"""scratch and cache folders no other user can plant in.

- a module planted in a world-writable ``<tmp>/dask-scratch-space`` (and ``-<uid>``) is never run:
  dask's scratch folder is the user's private folder (0700, owned, checked), not ``<tmp>``;
- the per-run TLS key never touches a disk (dask writes in-memory PEM to a temp folder; ours goes to
  an anonymous in-memory file);
- a cache folder opened to other users is passed over.
Everything under the test's own private TMPDIR (tmp_path), never the real /tmp."""
from __future__ import annotations

import os
import stat
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from atomicio import cache_dirs


def _plant(tmp: Path, mark: Path) -> None:
    for name in ("dask-scratch-space", f"dask-scratch-space-{os.getuid()}"):
        folder = tmp / name
        folder.mkdir()
        (folder / "tqdm.py").write_text(f"open({str(mark)!r}, 'w').write('planted code ran')\n")
        os.chmod(folder / "tqdm.py", 0o666)
        os.chmod(folder, 0o777)  # as another local user would leave it


@pytest.fixture()
def short_tmp():
    """A private (0700) TMPDIR with a short path: the process cluster's UNIX sockets live under TMPDIR, and
    pytest's per-worker tmp_path would push them past the 108-byte AF_UNIX limit."""
    import shutil
    import tempfile

    d = Path(tempfile.mkdtemp(prefix="slt-"))
    try:
        yield d
    finally:
        shutil.rmtree(d, ignore_errors=True)


def test_planted_module_in_shared_dask_scratch_is_never_run(scene, tmp_path, short_tmp):
    tmp = short_tmp
    mark = tmp_path / "mark"
    _plant(tmp, mark)
    env = {**os.environ, "TMPDIR": str(tmp), "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    out = subprocess.run([sys.executable, "-m", "straylight.cli.main", "trace", str(scene), "--rays", "2000",
                          "--json", str(tmp_path / "t.json"), "--workers", "2", "--processes"],
                         capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert not mark.exists(), "a module planted in <tmp>/dask-scratch-space ran as the user"


def test_dask_scratch_is_private():
    folder = cache_dirs.private_dir("dask-scratch")
    st = os.lstat(folder)
    assert stat.S_ISDIR(st.st_mode) and st.st_uid == os.getuid() and not st.st_mode & 0o022


def test_run_key_never_touches_disk(monkeypatch):
    pytest.importorskip("cryptography")
    if not hasattr(os, "memfd_create"):
        pytest.skip("no memfd_create on this platform: dask's temp-file way applies")
    from straylight.engine.backends.dask import run_security

    security = run_security()

    def no_disk(*a, **k):
        raise AssertionError("the TLS key was about to be written to a temporary folder")

    monkeypatch.setattr(tempfile, "TemporaryDirectory", no_disk)
    monkeypatch.setattr(tempfile, "mkdtemp", no_disk)
    args = security.get_connection_args("client")
    assert args["ssl_context"] is not None
    assert security.get_listen_args("scheduler")["ssl_context"] is not None


def test_run_security_pickles_for_worker_processes():
    pytest.importorskip("cryptography")
    import pickle

    from straylight.engine.backends.dask import run_security

    back = pickle.loads(pickle.dumps(run_security()))
    assert type(back).__name__ == "_MemorySecurity" and back.require_encryption


def test_cache_folder_opened_to_others_is_passed_over(tmp_path, monkeypatch):
    shared = tmp_path / "shared"
    (shared / "tessellation").mkdir(parents=True)
    os.chmod(shared / "tessellation", 0o777)
    os.chmod(shared / "tessellation", 0o777 | stat.S_ISVTX)
    other = tmp_path / "other"
    other.mkdir()
    monkeypatch.setenv("STRAYLIGHT_CACHE_DIR", str(shared))
    monkeypatch.setattr(cache_dirs, "_CHOSEN", {"root": other})
    # ours but opened to others: tightened (an older version under umask 002 made it so), then used
    assert cache_dirs.cache_dir("tessellation") == shared / "tessellation"
    assert not os.stat(shared / "tessellation").st_mode & 0o022
    with pytest.raises(cache_dirs.NotPrivateError, match="not a folder"):
        (tmp_path / "link").symlink_to(other)
        cache_dirs.check_private(tmp_path / "link")


def test_symlinked_cache_folder_is_not_used(tmp_path, monkeypatch):
    target = tmp_path / "elsewhere"
    target.mkdir()
    shared = tmp_path / "shared"
    shared.mkdir()
    (shared / "energy_check").symlink_to(target)  # a link planted where the cache would be
    monkeypatch.setenv("STRAYLIGHT_CACHE_DIR", str(shared))
    monkeypatch.setattr(cache_dirs, "_CHOSEN", {"root": tmp_path / "root"})
    assert cache_dirs.cache_dir("energy_check") == tmp_path / "root" / "energy_check"


def test_a_long_tmpdir_still_runs_a_process_cluster(scene, tmp_path):
    """Under a TMPDIR too long for a UNIX socket address (multiprocessing's fork server listens on
    <tmp>/pymp-*/listener-*: 108 bytes at most on Linux), ``--workers 2 --processes`` failed with "AF_UNIX
    path too long"; the workers now start by dask's spawn method there (same results)."""
    long_tmp = tmp_path / ("t" * 60) / ("u" * 60)
    long_tmp.mkdir(parents=True)
    os.chmod(long_tmp, 0o700)
    env = {**os.environ, "TMPDIR": str(long_tmp), "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    out = subprocess.run([sys.executable, "-m", "straylight.cli.main", "trace", str(scene), "--rays", "2000",
                          "--json", str(tmp_path / "t.json"), "--workers", "2", "--processes"],
                         capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert (tmp_path / "t.json").exists()


def test_the_fork_server_is_used_only_where_its_socket_fits(tmp_path, monkeypatch):
    import multiprocessing

    from straylight.engine.backends import fork_server

    # multiprocessing's own temp folder, once made in this process, is used instead of TMPDIR
    monkeypatch.delitem(getattr(multiprocessing.current_process(), "_config", {}), "tempdir", raising=False)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / ("v" * 120)))
    assert not fork_server.socket_path_fits() and not fork_server.wanted()
    monkeypatch.setattr(tempfile, "tempdir", "/tmp")
    assert fork_server.socket_path_fits()
