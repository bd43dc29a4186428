"""Dask for real: a ``--workers 2`` run opens no socket beyond this machine; worker
processes give the numbers of an in-process run; a worker killed mid-trace (SIGKILL to a real
``dask worker`` process on localhost) costs only its tasks, which dask reruns, and the numbers stay
identical (counter-based streams: a chunk's numbers do not depend on where or when it runs).

The expected numbers are the in-process trace's, an independent way of running the same chunks."""
from __future__ import annotations

import ipaddress
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import psutil
import pytest

from straylight.execution import Execution
from straylight.scene import load_scene
from straylight.trace import EstimatorOptions, TraceOptions, trace

GOLDEN = Path(__file__).resolve().parents[1] / "data" / "engine_golden"
OPTIONS = TraceOptions(batch_rays=1000)  # many small tasks, so a kill lands mid-trace


def listening_addresses(pid=None) -> list:
    """(pid, ip, port) of every listening TCP socket of process ``pid`` (default: this one) and its children."""
    root = psutil.Process(pid or os.getpid())
    out = []
    for proc in [root] + root.children(recursive=True):
        try:
            conns = proc.net_connections(kind="inet")
        except psutil.NoSuchProcess:
            continue
        out += [(proc.pid, c.laddr.ip, c.laddr.port) for c in conns if c.status == psutil.CONN_LISTEN]
    return out


def _non_loopback(addresses):
    return [a for a in addresses if not ipaddress.ip_address(a[1].split("%")[0]).is_loopback]


@pytest.fixture(scope="module")
def tube():
    rs = load_scene(GOLDEN / "tube.toml")
    reference = trace(rs.scene, rs.sources, 30_000, 5, materials=rs.materials, options=OPTIONS).to_json_dict()
    return rs, reference


def test_workers_2_listens_on_loopback_only(tube, tmp_path):
    """`straylight trace --workers 2` (its own argument parsing and client): every listening socket
    of the run is on 127.0.0.1 (dask's defaults opened two on 0.0.0.0: scheduler HTTP and worker HTTP)."""
    from straylight.cli.cluster_args import cluster_client
    from straylight.cli.main import build_parser

    rs, reference = tube
    args = build_parser().parse_args(["trace", str(GOLDEN / "tube.toml"), "--rays", "30000", "--workers", "2",
                                      "--json", str(tmp_path / "out.json")])
    before = set(listening_addresses())
    with cluster_client(args) as client:
        opened = set(listening_addresses()) - before
        res = trace(rs.scene, rs.sources, 30_000, 5, materials=rs.materials, options=OPTIONS, execution=Execution(client=client))
        opened |= set(listening_addresses()) - before
    assert client is not None and client.cluster.straylight_threads == 2
    assert not _non_loopback(opened), f"sockets open beyond this machine: {_non_loopback(opened)}"
    assert res.to_json_dict() == reference


def test_local_cluster_of_worker_processes_gives_identical_numbers(tube):
    from dask.distributed import Client

    from straylight.engine.backends.dask import local_cluster, warm_up
    from straylight.trace import make_spec

    rs, reference = tube
    with local_cluster(2, processes=True) as cluster, Client(cluster) as client:
        assert len(client.scheduler_info()["workers"]) == 2
        assert not _non_loopback(listening_addresses())
        spec = make_spec(rs.scene, rs.sources, 30_000, 5, rs.materials, OPTIONS)
        cpu = warm_up(client, spec)  # every worker builds its scene (the spec scattered, one task each)
        assert sorted(cpu) == sorted(client.scheduler_info()["workers"]) and min(cpu.values()) > 0
        assert client.run(_has_scene, spec.token) == {w: True for w in cpu}
        res = trace(rs.scene, rs.sources, 30_000, 5, materials=rs.materials, options=OPTIONS, execution=Execution(client=client))
    assert res.to_json_dict() == reference


def _has_scene(token):
    from straylight.engine.runtime import runtime

    return token in runtime().scene_tokens()


def _start(cmd, log):
    return subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)


def _stop(proc):
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)


def test_killed_dask_worker_process_gives_identical_numbers(tube, tmp_path):
    """A `dask scheduler` and two `dask worker --no-nanny` processes on localhost; one worker is
    killed with SIGKILL while it holds tasks. The trace finishes on the other with the same JSON."""
    from dask.distributed import Client

    rs, reference = tube
    sched_file = tmp_path / "scheduler.json"
    log = open(tmp_path / "dask.log", "w")
    py = [sys.executable, "-m", "dask"]
    procs = [_start(py + ["scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                          "--dashboard-address", "127.0.0.1:0", "--scheduler-file", str(sched_file)], log)]
    try:
        for _ in range(200):
            if sched_file.exists() and sched_file.stat().st_size:
                break
            time.sleep(0.1)
        for _ in range(2):
            procs.append(_start(py + ["worker", "--scheduler-file", str(sched_file), "--nthreads", "1", "--no-nanny",
                                      "--host", "127.0.0.1", "--no-dashboard", "--dashboard-address", "127.0.0.1:0"],
                                log))
        with Client(scheduler_file=str(sched_file), timeout=60) as client:
            client.wait_for_workers(2, timeout=120)
            pid_of = client.run(os.getpid)  # worker address -> pid
            assert sorted(pid_of.values()) == sorted(p.pid for p in procs[1:])
            done = {}
            runner = threading.Thread(target=lambda: done.update(res=trace(
                rs.scene, rs.sources, 30_000, 5, materials=rs.materials, options=OPTIONS, execution=Execution(client=client))))
            runner.start()
            victim = None
            deadline = time.monotonic() + 120
            while victim is None and runner.is_alive() and time.monotonic() < deadline:
                busy = [addr for addr, tasks in client.processing().items() if tasks]
                if busy:
                    victim = busy[0]
                    os.kill(pid_of[victim], signal.SIGKILL)
                time.sleep(0.005)
            runner.join(300)
            assert victim is not None, "no worker ever held a task"
            assert not runner.is_alive() and "res" in done
            assert len(client.scheduler_info()["workers"]) == 1  # the victim is gone for good
    finally:
        for proc in reversed(procs):
            _stop(proc)
        log.close()
    assert done["res"].to_json_dict() == reference, (tmp_path / "dask.log").read_text()[-2000:]


_FORK_SERVER_CHILD = r"""
import os, subprocess, sys, time
from pathlib import Path
import multiprocessing.forkserver as mp_forkserver
from dask.distributed import Client
from straylight.engine.backends import fork_server
from straylight.engine.backends.dask import local_cluster

if __name__ == "__main__":
    assert fork_server.start()
    server = mp_forkserver._forkserver._forkserver_pid
    env = {}
    for _ in range(200):  # a just-launched server may still be exec'ing: its environ reads empty
        env = dict(kv.split("=", 1) for kv in Path(f"/proc/{server}/environ").read_text().split("\0") if "=" in kv)
        if env:
            break
        time.sleep(0.05)
    assert env.get("OMP_NUM_THREADS") == "1" and env.get("OPENBLAS_NUM_THREADS") == "1", env
    assert env.get("PYTHONHASHSEED") not in (None, "0")
    expected = subprocess.run([sys.executable, "-c", "print(hash('straylight'))"], capture_output=True, text=True,
                              env=dict(os.environ, PYTHONHASHSEED=env["PYTHONHASHSEED"]), check=True).stdout.strip()
    with local_cluster(2, processes=True) as cluster, Client(cluster) as client:
        assert set(client.run(os.getppid).values()) == {server}
        assert set(client.run(hash, "straylight").values()) == {int(expected)}
    print("ok")
"""


def test_fork_server_started_early_is_the_one_the_workers_come_from_with_the_nanny_environment(tmp_path):
    """`straylight.engine.backends.fork_server.start` (called by `trace/pst --workers K --processes` before the scene
    loads) launches the server the cluster's workers are then forked from, with the environment
    dask's nanny would have given it: one OpenMP/OpenBLAS thread and PYTHONHASHSEED 6640, so the
    workers hash strings as a fresh interpreter with that seed does. In a fresh interpreter: a fork
    server is started once per process, and an earlier test may have started this one's."""
    script = tmp_path / "child.py"
    script.write_text(_FORK_SERVER_CHILD)
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "PYTHONHASHSEED")}
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300, env=env,
                          cwd=Path(__file__).resolve().parents[2])
    assert done.returncode == 0 and done.stdout.strip().endswith("ok"), done.stderr[-3000:]


def test_spec_shipped_early_and_tables_sent_apart_give_identical_numbers(tube):
    """With first- and second-vertex sampling the workers get the spec (triangles) before this
    process builds the tables (straylight.engine.backends.dask.ship_early) and then only the tables: the
    numbers are those of an in-process trace."""
    from dask.distributed import Client

    from straylight.engine.backends.dask import local_cluster

    rs, _ = tube
    opts = TraceOptions(estimator=EstimatorOptions(first_vertex_sampling=True, second_vertex_sampling=True), batch_rays=3000)
    local = trace(rs.scene, rs.sources, 12_000, 7, materials=rs.materials, options=opts)
    with local_cluster(2, processes=True) as cluster, Client(cluster) as client:
        res = trace(rs.scene, rs.sources, 12_000, 7, materials=rs.materials, options=opts, execution=Execution(client=client))
        again = trace(rs.scene, rs.sources, 12_000, 7, materials=rs.materials, options=opts, execution=Execution(client=client))
    assert local.detectors and all(d.power_w > 0 for d in local.detectors.values())
    assert res.to_json_dict() == local.to_json_dict()
    assert again.to_json_dict() == local.to_json_dict()


def test_early_shipment_sends_only_the_fields_that_changed(tube):
    """What a trace sends after :func:`ship_early`: the fields that are not the shipped spec's own
    objects (the tables), or everything (None) for a spec of another scene."""
    from dataclasses import replace

    from straylight.engine.backends.dask import EarlyShipment
    from straylight.trace import make_spec

    rs, _ = tube
    spec = make_spec(rs.scene, rs.sources, 1000, 1, rs.materials, OPTIONS)
    early = EarlyShipment(None, spec, None, [])
    table = object()
    assert early.changed(spec) == {}
    assert early.changed(replace(spec, vertex_table=table)) == {"vertex_table": table}
    moved = rs.scene.parts[0].vertices_mm + 1.0
    other = make_spec(type(rs.scene)((replace(rs.scene.parts[0], vertices_mm=moved),) + tuple(rs.scene.parts[1:])),
                      rs.sources, 1000, 1, rs.materials, OPTIONS)
    assert early.changed(other) is None


def test_fork_server_start_leaves_this_process_environment_as_it_was(monkeypatch):
    """The nanny's variables are given to the server's launch only (this process's numpy may not be
    imported yet: its BLAS threads are left as they would have been)."""
    import multiprocessing.forkserver as mp_forkserver

    from straylight.engine.backends import fork_server

    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    launched = []
    monkeypatch.setattr(mp_forkserver, "ensure_running",
                        lambda: launched.append((os.environ.get("OPENBLAS_NUM_THREADS"), os.environ["OMP_NUM_THREADS"])))
    assert fork_server.start()
    assert launched == [("1", "3")]  # the nanny keeps a variable that is set
    assert "OPENBLAS_NUM_THREADS" not in os.environ and os.environ["OMP_NUM_THREADS"] == "3"
