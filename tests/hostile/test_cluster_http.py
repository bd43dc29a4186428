"""Issue 39: without ``--dashboard`` the local cluster serves no HTTP at all. On main 13a6b5b the
scheduler's HTTP server listened on a loopback port (pages such as /info/call-stacks: worker call
stacks and paths readable by any local user), and so did each worker's."""
from __future__ import annotations

import os

import psutil

from straylight.engine.backends.dask import dask_client


def _listening_ports() -> set:
    me = psutil.Process(os.getpid())
    return {c.laddr.port for c in me.net_connections(kind="tcp") if c.status == psutil.CONN_LISTEN}


def test_in_process_cluster_listens_nowhere():
    before = _listening_ports()
    with dask_client(workers=2) as client:
        assert client is not None
        assert client.submit(sum, [1, 2]).result() == 3
        assert _listening_ports() - before == set()  # inproc:// scheduler, no HTTP port


def test_process_cluster_serves_no_http():
    before = _listening_ports()
    with dask_client(workers=1, processes=True) as client:
        comm = [client.scheduler.address] + [w["nanny"] for w in client.scheduler_info()["workers"].values()]
        tls_ports = {int(a.rsplit(":", 1)[1]) for a in comm}
        assert all(a.startswith("tls://127.0.0.1:") for a in comm)
        assert _listening_ports() - before == tls_ports  # the TLS comm ports (scheduler, nannies) only, no HTTP
        open_http = client.run(lambda dask_worker: sum(s.fileno() != -1 for s in dask_worker.http_server._sockets.values()))
        assert set(open_http.values()) == {0}
