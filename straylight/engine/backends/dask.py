"""Run trace batches on dask.distributed, combining results in chunk order.

A LocalCluster of one in-process worker whose tasks share a pool of ``workers`` threads by
default (:func:`local_cluster`), an existing ``Client``, or ``Client(scheduler_address)``. The
:class:`straylight.engine.spec.TraceSpec` (triangle array, materials, sources) is broadcast once; each worker process
builds its embree scene from the triangles on first use and keeps it (its :class:`straylight.engine.runtime.Runtime`), so no embree object is
ever pickled. Each task is a run of whole chunks (:func:`task_plan`) whose random streams are
keyed by chunk id, so the same seed gives the same numbers for any worker count.
"""
from __future__ import annotations

import asyncio
import datetime
import ipaddress
import logging
import os
import signal
import socket
import sys
import threading
import time
from contextlib import contextmanager
from dataclasses import fields, replace
from pathlib import Path

import numpy as np

from atomicio.cache_dirs import private_dir
from straylight.engine.backends import fork_server
from straylight.engine.backends.threads import run_threads
from straylight.engine.runtime import runtime
from straylight.engine.walk import run_batch

TASK_BATCHES = 5  # at most this many batches per dask task

# a LocalCluster made for tracing: the event loop shares the GIL (threads) or the cores (processes)
# with the workers, so its periodic housekeeping is slowed down (idle CPU 40 -> 7 ms per second) and
# work stealing, useless for equal independent tasks, is off
LEAN_CONFIG = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.worker.memory.monitor-interval": "1s",
    "distributed.scheduler.work-stealing": False,
}


def _group_task(spec, ranges, changed=None):
    spec = _joined(spec, changed)
    return [_packed(run_batch(spec, a, b)) for a, b in ranges]


def _joined(spec, changed):
    """The spec a task traces: the shipped ``spec`` with the fields in ``changed`` replaced (None:
    as shipped). See :func:`ship_early`."""
    if not changed:
        return spec
    return replace(spec, **changed)


def _packed(res: dict) -> dict:
    """A batch result for the trip to the client: its irradiance-map sums (per chunk and detector a
    triple of small arrays: bins, sum, sum of squares) as three concatenated arrays and the count
    of each entry (-1: none). Pickling ~150 small arrays per batch cost the worker ~0.9 ms and the
    client ~0.6 ms; packed, 0.3 and 0.25 ms (:func:`_unpacked` rebuilds the same entries as views,
    so the client adds the same numbers in the same order)."""
    maps = res["maps"]
    counts = np.full((len(maps), len(maps[0]) if maps else 0), -1, dtype=np.int64)
    parts: tuple[list, list, list] = ([], [], [])
    for c, row in enumerate(maps):
        for j, entry in enumerate(row):
            if entry is not None:
                counts[c, j] = len(entry[0])
                for k in range(3):
                    parts[k].append(entry[k])
    flat = [np.concatenate(p) if p else np.zeros(0) for p in parts]
    return {**res, "maps": None, "packed_maps": (counts, *flat)}


def _unpacked(res: dict) -> dict:
    """The batch result :func:`_packed` was made from (map entries as views into its arrays)."""
    if "packed_maps" not in res:
        return res
    counts, bins, s1, s2 = res.pop("packed_maps")
    n_det = counts.shape[1]
    maps, a = [], 0
    for row in counts.tolist():
        entries = []
        for n in row:
            entries.append(None if n < 0 else (bins[a:a + n], s1[a:a + n], s2[a:a + n]))
            a += max(n, 0)
        maps.append(entries if n_det else [])
    res["maps"] = maps
    return res


def _pooled_task(spec, ranges, n_threads, changed=None):
    """Queue whole batches on the worker's shared pool of ``n_threads`` threads
    (:meth:`straylight.engine.runtime.Runtime.pool`) and return their results in batch order. The worker runs
    ``n_threads`` such tasks at once, so the next task's batches are already queued when this one's
    last batch runs: the pool's threads never wait at task ends."""
    return list(run_threads(_joined(spec, changed), ranges, None, int(n_threads)))


def pooled_plan(ranges, n_threads: int) -> list:
    """Tasks for a pooled worker: runs of whole batches, a multiple of ``n_threads`` long (about
    half the run per task, at most 8 rounds of the pool), so a long run still reports progress
    task by task."""
    ranges = list(ranges)
    k = max(1, int(n_threads))
    per = k * max(1, min(8, -(-len(ranges) // (2 * k))))
    return [ranges[i:i + per] for i in range(0, len(ranges), per)]


def task_plan(ranges, n_slots: int) -> list:
    """Group batch ranges ``(first_chunk, stop_chunk)`` into dask tasks (lists of whole batches, in
    chunk order) of decreasing size (guided self-scheduling: about remaining / (2 slots) batches, at
    most TASK_BATCHES), so that few tasks carry the run (each costs the scheduler a few ms of CPU)
    and the last ones are single batches, so no worker thread idles long at the end. Batches are
    never cut: a small batch pays the per-event Python costs for few rays."""
    ranges = list(ranges)
    tasks = []
    k = 0
    while k < len(ranges):
        left = len(ranges) - k
        per = min(TASK_BATCHES, max(1, -(-left // (2 * max(1, int(n_slots))))))
        tasks.append(ranges[k:k + per])
        k += per
    return tasks


#: times a task cancelled under the run (its scattered spec lost with a killed worker) is submitted again
LOST_TASK_RETRIES = 3

LOOPBACK = "127.0.0.1"


def local_cluster(n_workers: int, processes: bool = False, dashboard: bool = False):
    """LocalCluster for tracing with ``n_workers`` parallel workers, reachable from this machine only:
    every socket (scheduler, workers, their HTTP servers) binds to 127.0.0.1 (an in-process cluster
    talks over ``inproc://``, with no scheduler port at all), and there is no dashboard unless
    ``dashboard`` (then on 127.0.0.1, a free port: ``cluster.dashboard_link``; needs bokeh). A dask
    scheduler runs whatever pickled task it is sent, so a port open to the network would let anyone
    run code as the user. Dask's statistical profiler is off (it samples every thread every 10 ms,
    ~5-10 % of a worker's CPU), with the housekeeping of :data:`LEAN_CONFIG`.

    Default: ONE in-process worker with ``n_workers`` dask threads whose tasks queue their batches
    on one shared pool of ``n_workers`` threads (:func:`_pooled_task`; the cluster carries
    ``straylight_threads = n_workers``). Embree and the compiled kernels release the GIL, and the
    threads share one copy of the scene. The tasks overlap, so the pool never idles at a task's
    end (tasks run one at a time on a private pool gave x1.61-1.90 from 1 to 2 workers on the
    reference tube; the shared pool x1.84-1.91, as a plain thread pool). 2 worker processes
    ran x1.77 by wall (each with its own scene and warm-up). ``processes=True`` gives ``n_workers``
    processes with one thread each; their scheduler listens on a loopback TCP port, which any
    process of the machine can reach, so it speaks TLS with a key made for this cluster alone
    (:func:`run_security`): a process without that key (another user, another program) cannot
    connect, let alone submit a task.

    dask's scratch folder (its ``temporary-directory``, which a worker puts first on ``sys.path``) is
    this user's private folder (:func:`atomicio.cache_dirs.private_dir`: 0700, ours, checked), never
    ``<tmp>/dask-scratch-space``, where another local user could plant a module."""
    import dask
    from dask.distributed import LocalCluster, Worker

    if dashboard:
        try:
            import bokeh  # noqa: F401 - dask's dashboard is drawn with bokeh
        except ImportError:
            raise RuntimeError("the dask dashboard needs bokeh: pip install 'straylight[dashboard]'") from None
    http = f"{LOOPBACK}:0"  # the scheduler's HTTP server (dashboard or not): loopback, a free port
    scheduler_kwargs = {"dashboard": bool(dashboard), "dashboard_address": http}

    class LoopbackWorker(Worker):
        """An in-process worker whose HTTP server listens on 127.0.0.1 (dask binds it to every
        interface when the worker itself has no TCP address)."""

        def __init__(self, *args, **kwargs):
            kwargs.update(dashboard=False, dashboard_address=http)
            super().__init__(*args, **kwargs)

    class PooledCluster(LocalCluster):
        """An in-process cluster whose tasks queue their batches on the worker's shared pool of
        ``straylight_threads`` threads (read by :func:`_run_on`)."""

        def __init__(self, *args, straylight_threads: int, **kwargs):
            self.straylight_threads = int(straylight_threads)
            super().__init__(*args, **kwargs)

    lean = {**LEAN_CONFIG, **({} if dashboard else NO_HTTP_ROUTES),
            "temporary-directory": str(private_dir("dask-scratch"))}  # never a shared <tmp> folder
    if processes:
        _quiet_handshakes()
        security = run_security()
        with dask.config.set({**lean, **_fork_server_config()}):
            cluster = _process_cluster_class()(n_workers=int(n_workers), threads_per_worker=1, processes=True,
                                               host=LOOPBACK, dashboard_address=None, scheduler_kwargs=scheduler_kwargs,
                                               protocol="tls://", security=security)
        return cluster if dashboard else _http_off(cluster)  # Client(cluster) takes the cluster's security
    runtime()  # this process's, started before the cluster's threads are (its in-process worker shares it)
    _quiet_handshakes()
    with dask.config.set(lean):
        cluster = PooledCluster(n_workers=1, threads_per_worker=int(n_workers), processes=False,
                                dashboard_address=None, scheduler_kwargs=scheduler_kwargs, worker_class=LoopbackWorker,
                                straylight_threads=int(n_workers))
    return cluster if dashboard else _http_off(cluster)


#: without --dashboard, the scheduler and workers serve no HTTP page (dask starts their HTTP servers
#: anyway, with pages such as /info/call-stacks that any local user could read)
NO_HTTP_ROUTES: dict[str, list] = {"distributed.scheduler.http.routes": [], "distributed.worker.http.routes": []}


def _stop_http(server) -> None:
    """Close ``server``'s HTTP listening sockets (a dask Scheduler or Worker; they serve no route)."""
    http = getattr(server, "http_server", None)
    if http is not None:
        http.stop()


def _http_off(cluster):
    """``cluster`` with no HTTP port: its scheduler's (in this process) and its in-process workers'
    HTTP servers closed; worker processes serve no route (:data:`NO_HTTP_ROUTES`) and close theirs
    when a client connects (:func:`dask_client`)."""
    _stop_http(cluster.scheduler)
    for worker in getattr(cluster, "workers", {}).values():
        if hasattr(worker, "http_server"):  # an in-process Worker (a Nanny holds its worker in another process)
            _stop_http(worker)
    return cluster


def run_security():
    """A dask ``Security`` made for one local cluster: a fresh self-signed certificate and key, held in
    this process's memory only (no file), given to the scheduler, the worker processes (through the
    nanny's pipe) and this process's clients, as ``distributed.Security.temporary`` does, but with an
    ECDSA P-256 key instead of RSA-2048 (made in ~1 ms instead of 0.1-0.4 s, and every TLS handshake
    between the cluster's processes signs faster). ``require_encryption``: every connection is TLS
    and must present that certificate, so nothing without the key talks to the scheduler."""
    try:
        from cryptography import x509
        from cryptography.hazmat.primitives import hashes, serialization
        from cryptography.hazmat.primitives.asymmetric import ec
        from cryptography.x509.oid import NameOID
    except ImportError:
        raise RuntimeError("a local cluster of worker processes needs the 'cryptography' package for its "
                           "per-run TLS key: pip install cryptography (or use --workers K without --processes)") from None
    key = ec.generate_private_key(ec.SECP256R1())
    key_pem = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                serialization.NoEncryption()).decode()
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "dask-internal")])  # the name dask's TLS expects
    now = datetime.datetime.now(tz=datetime.timezone.utc)
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name).public_key(key.public_key())
            .add_extension(x509.SubjectAlternativeName([x509.DNSName("dask-internal")]), critical=False)
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5)).not_valid_after(now + datetime.timedelta(days=30))
            .sign(key, hashes.SHA256()))
    cert_pem = cert.public_bytes(serialization.Encoding.PEM).decode()
    return MemorySecurity(require_encryption=True, tls_ca_file=cert_pem, tls_client_key=key_pem, tls_client_cert=cert_pem,
                    tls_scheduler_key=key_pem, tls_scheduler_cert=cert_pem, tls_worker_key=key_pem,
                    tls_worker_cert=cert_pem)


def _memory_file(text: str):
    """A file descriptor of an anonymous in-memory file (Linux ``memfd_create``) holding ``text``, and
    its path ``/proc/self/fd/N``; None where there is no such thing."""
    if not hasattr(os, "memfd_create") or not os.path.isdir("/proc/self/fd"):
        return None
    fd = os.memfd_create("straylight-tls", getattr(os, "MFD_CLOEXEC", 0))
    os.write(fd, text.encode())
    return fd, f"/proc/self/fd/{fd}"


def _security_class():
    from distributed.security import Security

    class _MemorySecurity(Security):
        """dask's ``Security`` whose in-memory PEM certificate and key never touch a disk: dask writes
        them to a temporary folder for ``ssl.load_cert_chain`` (which reads only files); here they
        go to anonymous in-memory files (``memfd_create``) instead, as the docs promise.
        Elsewhere (no memfd) dask's own way applies."""

        def _get_tls_context(self, tls, purpose):
            fds, tls = [], dict(tls)
            try:
                for name in ("cert", "key"):
                    text = tls.get(name)
                    if text and "\n" in text:
                        made = _memory_file(text)
                        if made is None:
                            break
                        fds.append(made[0])
                        tls[name] = made[1]
                return super()._get_tls_context(tls, purpose)
            finally:
                for fd in fds:
                    os.close(fd)

    _MemorySecurity.__qualname__ = _MemorySecurity.__name__  # pickled by name: the module's __getattr__
    globals()["_MemorySecurity"] = _MemorySecurity
    return _MemorySecurity


def __getattr__(name):
    """``_MemorySecurity`` made on first use (dask is imported only when a cluster is), so that worker
    processes can unpickle it by name."""
    if name == "_MemorySecurity":
        return _security_class()
    raise AttributeError(name)


def MemorySecurity(**kwargs):  # noqa: N802 - builds a Security
    """A :class:`distributed.Security` whose in-memory key stays in memory (:func:`_security_class`)."""
    cls = globals().get("_MemorySecurity") or _security_class()
    return cls(**kwargs)


INSECURE_ENV = "STRAYLIGHT_ALLOW_INSECURE_SCHEDULER"


def check_scheduler_address(address, allow_insecure=None) -> str | None:
    """Refuse a scheduler reached without encryption beyond this machine: anything that can reach a
    plain-TCP scheduler can run code as its workers' user, and this client unpickles what comes back.
    ``tls://`` (and ``wss://``) are encrypted and authenticated; a plain address on a loopback host is
    this machine's; anything else is a ValueError naming the address unless ``allow_insecure`` (the
    ``--allow-insecure`` flag; None: the environment variable ``STRAYLIGHT_ALLOW_INSECURE_SCHEDULER=1``),
    which returns a warning to print instead. Returns None when the address is fine."""
    text = str(address)
    protocol, _, rest = text.rpartition("://")
    protocol = protocol or "tcp"
    if protocol in ("tls", "wss", "inproc"):
        return None
    host = _address_host(rest)
    if host is not None and _is_loopback(host):
        return None
    if allow_insecure is None:
        allow_insecure = os.environ.get(INSECURE_ENV, "").strip().lower() in ("1", "yes", "true", "on")
    message = (f"--scheduler {text} is not encrypted ({protocol}://) and not on this machine: anyone who can "
               f"reach it can run code on its workers, and read or forge what they send back")
    if not allow_insecure:
        raise ValueError(f"{message}; use tls:// with --tls-ca-file/--tls-cert/--tls-key (docs/cluster.md), "
                         f"or pass --allow-insecure on a network you trust")
    return f"{message} (allowed by --allow-insecure)"


def _address_host(rest: str):
    """The host of ``host:port`` / ``[v6]:port`` / ``host``."""
    if rest.startswith("["):
        return rest[1:].split("]", 1)[0]
    if rest.count(":") > 1:  # a bare IPv6 address
        return rest
    return rest.split(":", 1)[0] or None


def _is_loopback(host: str) -> bool:
    """Does ``host`` name this machine only (every address it resolves to is a loopback address)?"""
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        pass
    try:
        infos = socket.getaddrinfo(host, None)
    except OSError:
        return False
    addresses = {str(info[4][0]).split("%")[0] for info in infos}
    return bool(addresses) and all(ipaddress.ip_address(a).is_loopback for a in addresses)


def _fork_server_config() -> dict:
    """Start local worker processes from a fork server that has imported dask and the engine and
    loaded the compiled kernels once (:mod:`straylight.engine.backends.preload`), instead of spawning fresh
    interpreters that each import and load all of it (~1.5 s CPU per worker, K of them at once).
    The server is launched here with the engine's preload list (:func:`straylight.engine.backends.fork_server.start`;
    a no-op if the command launched it earlier, so that it loaded while the scene loaded) before the
    cluster starts, and kept for this process's later clusters: dask's own preload list, which it
    sets when its nanny first asks for the forkserver context, no longer reaches a running server
    (``multiprocessing.set_forkserver_preload`` applies to the next server launched). dask then
    still imports its optional packages here (pandas if installed: ~0.15-0.2 CPU-s, once).
    Not done when dask's start method was configured otherwise (``distributed.worker.multiprocessing-method``).
    Returns the dask config to start the cluster with."""
    if not fork_server.start():
        return {}  # the user's choice (or no fork on this platform)
    return {"distributed.worker.multiprocessing-method": "forkserver"}


WORKER_STOP_S = 0.1  # grace a finished local worker process gets to exit before it is killed


def _process_cluster_class():
    """LocalCluster whose close stops its worker processes at once: dask's graceful stop let an idle
    worker process linger ~1 s (up to 4 s on a loaded machine) before it exited, added to every
    command's wall time. The nannies kill their processes after :data:`WORKER_STOP_S` (each holds
    nothing the client still needs: results are gathered before the cluster is closed); the
    scheduler and the nannies then close as usual."""
    from dask.distributed import LocalCluster
    from distributed.core import Status

    class FastStopCluster(LocalCluster):
        async def _close(self):
            if self.status == Status.running:
                log = logging.getLogger("distributed.nanny")
                level = log.level
                log.setLevel(logging.ERROR)  # "still alive after 0.1 s, killing" is the plan here
                try:
                    await asyncio.gather(*(w.close(timeout=WORKER_STOP_S / 0.8, reason="straylight: cluster done")
                                           for w in list(self.workers.values()) if hasattr(w, "kill")),
                                         return_exceptions=True)
                finally:
                    log.setLevel(level)
            await super()._close()

    return FastStopCluster


def tls_security(ca_file=None, cert=None, key=None):
    """A dask ``Security`` for TLS from PEM files (as ``dask scheduler/worker --tls-ca-file --tls-cert
    --tls-key``), or None when no file is given (then dask's own configuration applies, e.g.
    ``distributed.comm.tls`` in ~/.config/dask/*.yaml). Missing files are an error naming the flag."""
    given = {"--tls-ca-file": ca_file, "--tls-cert": cert, "--tls-key": key}
    if not any(given.values()):
        return None
    for flag, path in given.items():
        if path is not None and not Path(path).is_file():
            raise FileNotFoundError(f"{flag} {path}: no such file")
    if not (ca_file and cert):
        raise ValueError("TLS needs --tls-ca-file and --tls-cert (and --tls-key unless the key is in the cert file)")
    from dask.distributed import Security

    return Security(tls_ca_file=str(ca_file), tls_client_cert=str(cert), tls_client_key=str(key) if key else None,
                    require_encryption=True)


@contextmanager
def dask_client(workers=None, scheduler=None, security=None, dashboard=False, in_process_below=1, processes=False,
                allow_insecure=None):
    """The one dask client builder: ``Client(scheduler, security=security)`` for a running scheduler;
    else, for ``workers`` >= ``in_process_below``, a :func:`local_cluster` of ``workers`` (loopback
    only; ``processes``: that many worker processes, else threads) and its client; else None (run in
    this process). Closed on exit.

    ``in_process_below``: worker counts below it run in-process (sweeps pass 2: one worker is just
    this process); ``trace(..., execution=Execution(workers=1))`` passes 1 and gets a one-thread cluster.

    A ``scheduler`` reached unencrypted beyond this machine is refused unless ``allow_insecure``
    (:func:`check_scheduler_address`; then a warning on stderr)."""
    if scheduler:
        from dask.distributed import Client

        warning = check_scheduler_address(scheduler, allow_insecure)
        if warning:
            print(f"straylight: warning: {warning}", file=sys.stderr)
        with _quiet_after_interrupt() as quiet, Client(scheduler, security=security) as client, quiet:
            yield client
    elif workers is not None and int(workers) >= max(1, int(in_process_below)):
        from dask.distributed import Client

        n = int(workers)
        with _quiet_after_interrupt() as quiet, local_cluster(n, processes=processes, dashboard=dashboard) as cluster, \
                Client(cluster) as client, quiet:
            if dashboard:
                print(f"straylight: dask dashboard at {cluster.dashboard_link} (this machine only)", file=sys.stderr)
            elif processes:
                client.run(_stop_worker_http)  # each worker process closes its HTTP port
            if processes:
                client.run(_quiet_handshakes)  # and says nothing of other processes' failed handshakes
            yield client
    else:
        if workers is not None and int(workers) < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        yield None


@contextmanager
def _quiet_after_interrupt():
    """After Ctrl-C, dask's own account of the tasks it drops ("Couldn't gather keys ... forgotten",
    "rescheduling ...") is not printed: the run says "interrupted" in one line. Used as
    ``with _quiet_after_interrupt() as quiet, <cluster and client>, quiet:``: the inner ``quiet``
    raises distributed's loggers to CRITICAL when a KeyboardInterrupt passes, before the client and
    cluster close; the outer one restores their level after they closed. Tornado's event-loop logger too:
    a future of the client's that the closing cluster leaves with CommClosedError is logged there as
    "Exception in callback ..." with its traceback (seen once in CI, timing-dependent)."""
    logs = [logging.getLogger("distributed"), logging.getLogger("tornado.application")]
    levels = [log.level for log in logs]

    def silence():
        for log in logs:
            log.setLevel(logging.CRITICAL)

    @contextmanager
    def quiet():
        try:
            yield
        except KeyboardInterrupt:
            silence()
            raise

    with _silenced_on_sigint(silence):
        try:
            yield quiet()
        finally:
            for log, level in zip(logs, levels):
                log.setLevel(level)


@contextmanager
def _silenced_on_sigint(silence):
    """While inside, a SIGINT first calls ``silence`` and then raises KeyboardInterrupt as Python's own handler does:
    the scheduler's thread may log the tasks it drops while the KeyboardInterrupt is still unwinding toward
    :func:`_quiet_after_interrupt`'s ``quiet`` (a full local test run under load once showed "Couldn't gather keys"
    above "straylight: interrupted"). Only from the main thread and over Python's default handler (a handler the
    caller installed stays theirs)."""
    if threading.current_thread() is not threading.main_thread() \
            or signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        yield
        return

    def on_sigint(signum, frame):
        silence()
        signal.default_int_handler(signum, frame)

    signal.signal(signal.SIGINT, on_sigint)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)


class _NoForeignHandshakes:
    """A logging filter for dask's noise on the user's terminal: "TLS handshake failed with
    remote ..." (any local process, another user's port scan or a browser, that touches the cluster's
    TLS port; it never got in: tests/straylight/test_cluster_security.py) and, after Ctrl-C, "Async
    instruction for <Task cancelled ...> ended with CancelledError" (the run says "interrupted")."""

    NOISE = ("TLS handshake failed", "ended with CancelledError")

    def filter(self, record) -> bool:
        message = record.getMessage()
        return not any(n in message for n in self.NOISE)


QUIET_LOGGERS = ("distributed.comm.tcp", "distributed.worker.state_machine")


def _quiet_handshakes(dask_worker=None) -> bool:
    """Install :class:`_NoForeignHandshakes` on :data:`QUIET_LOGGERS` in this process (once)."""
    for name in QUIET_LOGGERS:
        log = logging.getLogger(name)
        if not any(isinstance(f, _NoForeignHandshakes) for f in log.filters):
            log.addFilter(_NoForeignHandshakes())
    return True


def _stop_worker_http(dask_worker=None):
    """Run on each worker process (``client.run``): close its HTTP server's port."""
    if dask_worker is not None:
        _stop_http(dask_worker)
    return True


def _warm_task(spec):
    run_batch(spec, 0, 1)
    return time.process_time()


def register_runtime(client) -> None:
    """Have every worker of ``client``, and any that joins later, set up its process's Runtime
    (:class:`straylight.engine.backends.worker_plugin.RuntimePlugin`, registered with distributed's
    public ``Client.register_plugin``; idempotent: once per cluster, a later registration is a no-op)."""
    from straylight.engine.backends.worker_plugin import RuntimePlugin

    client.register_plugin(RuntimePlugin())


def warm_up(client, spec) -> dict:
    """Build the scene (embree + compiled kernels) in every worker of ``client`` now, by tracing the
    first chunk of ``spec`` on each (so that start-up is not charged to the first real tasks).
    Returns {worker address: process CPU seconds so far}. The spec is scattered once to every
    worker and the chunk runs as a task there: sent as an argument of ``client.run`` it went
    through the scheduler to each worker (0.36M triangles: ~0.7 s, vs ~0.1 s scattered)."""
    register_runtime(client)
    future = client.scatter(spec, broadcast=True, hash=False)
    workers = sorted(client.scheduler_info().get("workers", {}))
    tasks = [client.submit(_warm_task, future, workers=[w], allow_other_workers=False, pure=False) for w in workers]
    try:
        return dict(zip(workers, client.gather(tasks)))
    finally:
        for fut in [future, *tasks]:
            fut.release()


def _build_task(spec):
    """Build this worker's scene of ``spec`` now (embree BVH, triangle planes, detector tables:
    :meth:`straylight.engine.runtime.Runtime.scene`, kept for the trace's tasks)."""
    runtime().scene(spec).isect._scene  # waits for the BVH build thread


class EarlyShipment:
    """A spec shipped to every worker before the trace (:func:`ship_early`): its future, the spec
    itself, and the futures of the workers' scene builds (kept so the scheduler runs them)."""

    def __init__(self, client, spec, future, builds):
        self.client, self.spec, self.future, self.builds = client, spec, future, builds

    def changed(self, spec):
        """{field: value} of ``spec`` where it differs from the shipped spec (compared by identity:
        a field holding the same object is the same), or None if ``spec`` is of another scene (then
        it is shipped whole)."""
        if spec.token != self.spec.token or type(spec) is not type(self.spec):
            return None
        return {f.name: getattr(spec, f.name) for f in fields(spec) if getattr(spec, f.name) is not getattr(self.spec, f.name)}

    def release(self):
        for fut in [self.future, *self.builds]:
            fut.release()


def ship_early(client, spec) -> EarlyShipment:
    """Send ``spec`` to every worker of ``client`` now and have each build its scene of it (one
    task per worker, :func:`_build_task`), without waiting: the workers build their embree scenes
    while this process does other work (e.g. builds the first-/second-vertex tables, which need
    this process's own scene; ``straylight.trace.trace``). A trace of a spec that differs from
    ``spec`` only in small fields (the tables) then ships just those fields
    (:func:`run_distributed` ``early=``): the triangles (27 MB for 0.36M triangles) travel once."""
    register_runtime(client)
    future = client.scatter(spec, broadcast=True, hash=False)
    workers = sorted(client.scheduler_info().get("workers", {}))
    builds = [client.submit(_build_task, future, workers=[w], allow_other_workers=False, pure=False)
              for w in workers]
    return EarlyShipment(client, spec, future, builds)


def worker_cpu_seconds(client) -> dict:
    """{worker address: CPU seconds used by that worker process so far} (``time.process_time``)."""
    return client.run(time.process_time)


def run_distributed(spec, ranges, workers=None, client=None, scheduler=None, security=None, early=None):
    """Yield ``run_batch`` results for ``ranges`` (list of (first_chunk, stop_chunk)), in order: on
    ``client``, else on a client of :func:`dask_client` (``scheduler``, or a local cluster of
    ``workers``) opened and closed for this trace. ``early``: an :class:`EarlyShipment` of a spec
    like ``spec`` already on ``client``'s workers (only the fields that differ are sent; released
    at the end)."""
    if client is not None:
        try:
            yield from _run_on(client, spec, ranges, early if early is not None and early.client is client else None)
        finally:
            if early is not None:
                early.release()
        return
    n = 1 if workers is None else int(workers)
    if n < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    with dask_client(n, scheduler, security=security) as own:
        yield from _run_on(own, spec, ranges)


def _run_on(client, spec, ranges, early=None):
    from dask.distributed import as_completed

    register_runtime(client)
    changed = early.changed(spec) if early is not None else None
    if changed is None:
        # a fresh key for every trace (hash=False): with the content's hash as key, a trace repeated
        # with the same spec re-scattered a key whose release by the previous trace was still on its
        # way, and the scheduler dropped the data under the new tasks (FutureCancelledError)
        spec_future = client.scatter(spec, broadcast=True, hash=False)
    else:  # the spec is on the workers already: send the fields that differ (the tables), once
        spec_future = early.future
        changed = client.scatter([changed], broadcast=True, hash=False)[0] if changed else None
    # few tasks (each costs the scheduler a few ms of CPU, which competes with the workers on a
    # small machine), shrinking toward the end for balance: task_plan (the numbers are unchanged)
    pool = int(getattr(getattr(client, "cluster", None), "straylight_threads", 0) or 0)
    if pool > 1:  # our local cluster: a thread pool inside each task (local_cluster)
        groups = pooled_plan(ranges, pool)
        futures = client.map(_pooled_task, [spec_future] * len(groups), groups, [pool] * len(groups),
                             [changed] * len(groups), pure=False)
    else:
        workers_info = client.scheduler_info().get("workers", {})
        n_slots = max(1, sum(int(w.get("nthreads", 1)) for w in workers_info.values()))
        groups = task_plan(ranges, n_slots)
        futures = client.map(_group_task, [spec_future] * len(groups), groups, [changed] * len(groups), pure=False)
    order = {fut.key: k for k, fut in enumerate(futures)}
    retries = [0] * len(groups)
    done = {}
    nxt = 0
    # results as they finish (one event-loop round trip for each), yielded in chunk order; raise_errors=False:
    # a task cancelled because a killed worker took the last copy of the scattered spec with it is resubmitted
    # (its chunks' own streams give the same numbers wherever it runs)
    results = as_completed(futures, with_results=True, raise_errors=False)
    for fut, result in results:
        k = order.pop(fut.key)
        if fut.status == "cancelled" and retries[k] < LOST_TASK_RETRIES:
            retries[k] += 1
            if spec_future.status != "finished":  # the spec is gone from every worker: scatter it again, whole
                spec_future = client.scatter(spec, broadcast=True, hash=False)
                changed = None
            fn, extra = (_pooled_task, (pool,)) if pool > 1 else (_group_task, ())
            again = client.submit(fn, spec_future, groups[k], *extra, changed, pure=False)
            order[again.key] = k
            results.add(again)
            continue
        if fut.status != "finished":
            fut.result()  # raises the task's error (or the cancellation)
        done[k] = result
        fut.release()
        while nxt in done:
            yield from (_unpacked(res) for res in done.pop(nxt))
            nxt += 1
