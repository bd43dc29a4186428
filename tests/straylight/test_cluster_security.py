"""Local clusters only the user can use: a ``--workers K --processes`` cluster's
scheduler listens on a loopback port that every process of the machine can reach, so it speaks TLS
with a key made for the run; a process without that key cannot connect (plain TCP, TLS without a
certificate, TLS with a certificate of its own), so it cannot submit work. An unencrypted scheduler
beyond this machine is refused in one line unless the user says ``--allow-insecure``."""
from __future__ import annotations

import asyncio
import gc
from pathlib import Path

import dask
import pytest

from straylight.engine.backends.dask import check_scheduler_address

SCENE = Path(__file__).resolve().parents[1] / "data" / "engine_golden" / "tube.toml"


def _add_one(x):
    return x + 1


async def _intrude(address: str, security=None) -> int:
    """Connect to ``address`` as another client and run a task; the client is closed explicitly
    whatever happens. (A synchronous ``Client`` whose constructor fails is left for the garbage
    collector, and its ``__del__`` closes it through the event loop's thread: when the collector
    runs on that thread, the close waits on itself and the test hangs. An asynchronous client,
    awaited and closed here, leaves nothing behind.)"""
    from distributed import Client

    client = Client(address, security=security, asynchronous=True, timeout="2s", set_as_default=False)
    try:
        await client
        return await asyncio.wait_for(client.submit(_add_one, 1), 2)
    finally:
        await asyncio.wait_for(client.close(), 5)


def test_process_cluster_refuses_clients_without_the_run_key():
    from distributed import Client, Security

    from straylight.engine.backends.dask import local_cluster

    with local_cluster(1, processes=True) as cluster, Client(cluster, set_as_default=False) as client:
        address = cluster.scheduler_address
        assert address.startswith("tls://127.0.0.1:")
        assert client.submit(_add_one, 1).result() == 2  # the run's own client works
        attempts = {"plain tcp": (address.replace("tls://", "tcp://"), None),
                    "tls, no certificate": (address, None),
                    "tls, another certificate": (address, Security.temporary())}
        with dask.config.set({"distributed.comm.timeouts.connect": "2s"}):
            for label, (target, security) in attempts.items():
                with pytest.raises(Exception):  # noqa: B017 - any failure to connect is the point
                    asyncio.run(_intrude(target, security))
                    pytest.fail(f"{label}: a client without the run's key ran a task")
        gc.collect()  # any client object left would be finalised now, inside the test's time limit
        assert client.submit(_add_one, 2).result() == 3  # and the run goes on


@pytest.mark.parametrize("address", ["tcp://192.0.2.7:8786", "192.0.2.7:8786", "ucx://192.0.2.7:8786",
                                     "tcp://[2001:db8::1]:8786", "tcp://no-such-host.invalid:8786"])
def test_unencrypted_remote_scheduler_is_refused(address):
    with pytest.raises(ValueError, match="not encrypted.*--allow-insecure"):
        check_scheduler_address(address)
    warning = check_scheduler_address(address, allow_insecure=True)
    assert "not encrypted" in warning and "allowed by --allow-insecure" in warning


@pytest.mark.parametrize("address", ["tls://192.0.2.7:8786", "tcp://127.0.0.1:8786", "tcp://localhost:8786",
                                     "tcp://[::1]:8786", "inproc://192.0.2.7/1/2"])
def test_encrypted_or_loopback_scheduler_is_accepted(address):
    assert check_scheduler_address(address) is None


def test_cli_refuses_a_remote_plain_scheduler_before_any_work(tmp_path, capsys, monkeypatch):
    """``straylight trace --scheduler tcp://REMOTE``: one line, exit 2, no connection attempted
    (dask's Client is replaced by a tripwire) and no scene loaded."""
    import distributed

    from straylight.cli.main import main

    def tripwire(*args, **kwargs):
        raise AssertionError("a connection was attempted")

    monkeypatch.setattr(distributed, "Client", tripwire)
    monkeypatch.setattr("dask.distributed.Client", tripwire)
    code = main(["trace", str(SCENE), "--rays", "1000", "--json", str(tmp_path / "o.json"),
                 "--scheduler", "tcp://192.0.2.7:8786"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "not encrypted" in err[0] and "--allow-insecure" in err[0]
    assert not (tmp_path / "o.json").exists()
