"""The fork server of a local cluster's worker processes, started early.

A local cluster of worker processes (``straylight.engine.backends.dask.local_cluster(K, processes=True)``)
forks its workers from a server process that imports dask and the engine and loads the compiled
kernels once (:mod:`straylight.engine.backends.preload`): ~1.5 s of one core before the first worker can
start, which dask's nanny would start only when the cluster starts, after the scene is loaded.
:func:`start` launches that server at once (it returns at once; the server loads in its own
process), so a command that knows it will open such a cluster (``straylight trace --workers K
--processes``) starts it before loading its scene and the two overlap on two cores; the cluster's
workers are then forked from the running server.

The server is launched exactly as dask would launch it at its first worker: with the preload list
of :data:`PRELOAD` and with the environment dask's nanny puts into this process's environment
before it starts a worker process (``distributed.nanny.pre-spawn-environ``, e.g. one OpenBLAS
thread, and ``PYTHONHASHSEED`` fixed as the nanny fixes it), because the forked workers inherit
the server's interpreter and libraries as they were loaded. Light on purpose: it imports dask's
configuration but not ``distributed`` (~0.65 s) nor the engine; dask's defaults of the two
settings it reads come from distributed's own ``distributed.yaml`` unless the user configured them.
"""
from __future__ import annotations

import importlib.util
import multiprocessing
import os
import sys
import tempfile
from multiprocessing import forkserver
from pathlib import Path

PRELOAD = ["distributed", "straylight.engine.backends.preload"]
NANNY_HASH_SEED = "6640"  # the PYTHONHASHSEED dask's nanny sets when none is given (distributed.nanny.Nanny)
_UNSET = object()


def _distributed_default(key: str):
    """The default of a ``distributed.*`` setting from distributed's ``distributed.yaml`` (what
    ``import distributed`` gives dask's config), read without importing distributed; None if absent."""
    import dask.config

    spec = importlib.util.find_spec("distributed")
    if spec is None or not spec.origin:
        return None
    node = next(iter(dask.config.collect_yaml([str(Path(spec.origin).parent / "distributed.yaml")])), None)
    for part in key.split("."):
        if not isinstance(node, dict) or part not in node:
            return None
        node = node[part]
    return node


def config(key: str):
    """dask's setting ``key`` (the user's configuration, else distributed's default)."""
    import dask

    got = dask.config.get(key, default=_UNSET)
    return _distributed_default(key) if got is _UNSET else got


def wanted() -> bool:
    """Will a local process cluster start its workers from our fork server? Yes unless dask's start
    method was configured otherwise (``distributed.worker.multiprocessing-method``) or the platform
    cannot fork. :func:`straylight.engine.backends.dask.local_cluster` asks the same."""
    return sys.platform != "win32" and config("distributed.worker.multiprocessing-method") == "spawn" \
        and socket_path_fits()


AF_UNIX_PATH_MAX = 107  # bytes of a socket path on Linux (sun_path[108] with its NUL); macOS: 103


def socket_path_fits() -> bool:
    """Does the fork server's socket fit in an AF_UNIX address? multiprocessing listens on
    ``<tmp>/pymp-XXXXXXXX/listener-XXXXXXXX``; under a long TMPDIR that path is too long and the
    server fails ("AF_UNIX path too long"). Then the workers are started by dask's own spawn method
    instead (slower to start, same results)."""
    base = getattr(multiprocessing.current_process(), "_config", {}).get("tempdir") or os.path.join(tempfile.gettempdir(), "pymp-xxxxxxxx")
    limit = 103 if sys.platform == "darwin" else AF_UNIX_PATH_MAX
    return len(os.fsencode(os.path.join(base, "listener-xxxxxxxx"))) <= limit


def nanny_environ() -> dict:
    """The variables dask's nanny puts into this process's environment before it starts a worker
    process: ``distributed.nanny.pre-spawn-environ`` (a variable already set keeps its value; None
    unsets nothing) and PYTHONHASHSEED (the nanny's fixed seed when unset or 0)."""
    cfg = config("distributed.nanny.pre-spawn-environ") or {}
    env = {k: os.environ.get(k, str(v)) for k, v in cfg.items() if v is not None}
    if env.get("PYTHONHASHSEED") in (None, "0"):
        env["PYTHONHASHSEED"] = NANNY_HASH_SEED
    return env


def start() -> bool:
    """Launch the fork server now, if a local process cluster would use it (:func:`wanted`), and
    return at once (True if launched or already running). Its ~1.5 s of loading runs in its own
    process while this one goes on (e.g. loads the scene). The nanny's environment is set for the
    server's launch only; this process's is restored (the nanny sets it here when the cluster
    starts, as before)."""
    if not wanted():
        return False
    env = nanny_environ()
    saved = {k: os.environ.get(k) for k in env}
    os.environ.update(env)  # for the server only: as the nanny sets it before it starts a worker process
    try:
        multiprocessing.get_context("forkserver").set_forkserver_preload(PRELOAD)
        forkserver.ensure_running()  # spawns the server now, with this environment
    finally:  # this process keeps its own (e.g. its BLAS threads, if numpy is not imported yet) until the nanny's
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    return True
