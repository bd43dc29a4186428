"""Without ``--dashboard`` the local cluster serves no HTTP at all. On main 13a6b5b the
scheduler's HTTP server listened on a loopback port (pages such as /info/call-stacks: worker call
stacks and paths readable by any local user), and so did each worker's."""
from __future__ import annotations

import logging
import os
import socket
import time

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


class _Kept(logging.Handler):
    def __init__(self):
        super().__init__()
        self.lines = []

    def emit(self, record):
        self.lines.append(record.getMessage())


def test_process_cluster_serves_no_http_and_stays_quiet():
    kept = _Kept()
    logging.getLogger("distributed.comm.tcp").addHandler(kept)  # sees what the terminal's handler would
    before = _listening_ports()
    with dask_client(workers=1, processes=True) as client:
        comm = [client.scheduler.address] + [w["nanny"] for w in client.scheduler_info()["workers"].values()]
        tls_ports = {int(a.rsplit(":", 1)[1]) for a in comm}
        assert all(a.startswith("tls://127.0.0.1:") for a in comm)
        assert _listening_ports() - before == tls_ports  # the TLS comm ports (scheduler, nannies) only, no HTTP
        open_http = client.run(lambda dask_worker: sum(s.fileno() != -1 for s in dask_worker.http_server._sockets.values()))
        assert set(open_http.values()) == {0}
        host, port = client.scheduler.address.rsplit("//", 1)[1].rsplit(":", 1)
        with socket.create_connection((host, int(port))) as intruder:  # another local process knocks
            intruder.sendall(b"GET / HTTP/1.0\r\n\r\n")
            time.sleep(0.5)
        time.sleep(0.5)
    logging.getLogger("distributed.comm.tcp").removeHandler(kept)
    assert not [m for m in kept.lines if "TLS handshake failed" in m], kept.lines  # main: a WARNING line per knock
