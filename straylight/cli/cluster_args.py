"""Where a command runs: the one place the command line turns its flags into an
:class:`straylight.execution.Execution` (:func:`execution`), and the options for running on dask,
shared by trace, pst and study: ``--processes``, ``--dashboard`` and the TLS files of a secured
scheduler (``--tls-ca-file``, ``--tls-cert``, ``--tls-key``, as ``dask scheduler`` / ``dask worker`` take
them). See docs/cluster.md."""
from __future__ import annotations

from contextlib import contextmanager

from straylight.execution import Execution


def add_cluster_args(parser) -> None:
    g = parser.add_argument_group("dask cluster (docs/cluster.md)")
    g.add_argument("--processes", action="store_true",
                   help="with --workers K: K worker processes with one thread each (each its own copy of the scene) "
                        "instead of one process with K threads; loopback only, same numbers")
    g.add_argument("--dashboard", action="store_true",
                   help="with --workers: serve dask's dashboard on 127.0.0.1 and print its address (needs bokeh)")
    g.add_argument("--tls-ca-file", metavar="CA.pem", help="with --scheduler tls://...: CA certificate")
    g.add_argument("--tls-cert", metavar="CERT.pem", help="with --scheduler tls://...: this client's certificate")
    g.add_argument("--tls-key", metavar="KEY.pem", help="with --scheduler tls://...: its private key")
    add_insecure_arg(g)


def add_insecure_arg(parser) -> None:
    """``--allow-insecure``: accept a plain-TCP scheduler beyond this machine (refused otherwise:
    :func:`straylight.engine.backends.dask.check_scheduler_address`)."""
    parser.add_argument("--allow-insecure", action="store_true",
                        help="accept --scheduler tcp://HOST on another machine without TLS (anyone who can reach "
                             "it can run code on its workers); only on a network you trust")


def start_early(args, in_process_below: int = 1) -> bool:
    """With ``--workers K --processes`` (K >= ``in_process_below``, no ``--scheduler``): launch the
    worker processes' fork server now (:func:`straylight.engine.backends.fork_server.start`), before the command
    loads its scene, so that its ~1.5 s of loading overlaps the scene's; :func:`cluster_client`
    then starts the cluster from it. Returns whether it was launched (or was running). An unencrypted
    ``--scheduler`` beyond this machine is refused here, before the scene is loaded."""
    workers = getattr(args, "workers", None)
    if getattr(args, "scheduler", None):  # an unencrypted remote scheduler is refused before any work
        from straylight.engine.backends.dask import check_scheduler_address

        check_scheduler_address(args.scheduler, getattr(args, "allow_insecure", False) or None)
    if not getattr(args, "processes", False) or getattr(args, "scheduler", None) or workers is None:
        return False
    if workers < max(1, int(in_process_below)):
        return False
    from straylight.engine.backends import fork_server

    return fork_server.start()


@contextmanager
def cluster_client(args, in_process_below: int = 1):
    """The dask client the options ask for (``--workers K``: a loopback-only local cluster of K threads,
    or K processes with ``--processes``; ``--scheduler``: that scheduler, with TLS if given), or None to
    run in this process (also for ``--workers`` below ``in_process_below``: sweeps run one worker here)."""
    workers, scheduler = getattr(args, "workers", None), getattr(args, "scheduler", None)
    dashboard, processes = getattr(args, "dashboard", False), getattr(args, "processes", False)
    tls_files = (getattr(args, "tls_ca_file", None), getattr(args, "tls_cert", None), getattr(args, "tls_key", None))
    security = None
    if any(tls_files):
        from straylight.engine.backends.dask import tls_security

        security = tls_security(*tls_files)
    if security is not None and not scheduler:
        raise ValueError("--tls-ca-file/--tls-cert/--tls-key apply to --scheduler only (a local cluster uses no network)")
    if dashboard and not workers:
        raise ValueError("--dashboard needs --workers K (a remote scheduler serves its own dashboard)")
    if processes and not workers:
        raise ValueError("--processes needs --workers K (the number of worker processes)")
    if workers is not None and workers < 1:
        raise ValueError(f"--workers must be >= 1, got {workers}")
    if getattr(args, "allow_insecure", False) and not scheduler:
        raise ValueError("--allow-insecure applies to --scheduler only")
    if not scheduler and (workers is None or workers < max(1, int(in_process_below))):
        yield None  # this process runs it (dask_client's answer too), without importing the dask backend
        return
    from straylight.engine.backends.dask import dask_client

    with dask_client(workers, scheduler, security=security, dashboard=dashboard,
                     in_process_below=in_process_below, processes=processes,
                     allow_insecure=getattr(args, "allow_insecure", False) or None) as client:
        yield client


def forked_execution(args):
    """The :class:`straylight.execution.Execution` of a command whose ``--workers K`` forks K processes of its
    own (``straylight ghosts``: no dask): ``Execution(workers=K)``, or None without the flag (the command's
    own default)."""
    workers = getattr(args, "workers", None)
    if workers is not None and workers < 1:
        raise ValueError(f"--workers must be >= 1, got {workers}")
    return None if workers is None else Execution(workers=workers)


@contextmanager
def execution(args, in_process_below: int = 1, in_process: bool = False):
    """The :class:`straylight.execution.Execution` of a command, from its flags: ``--threads K``,
    ``--workers K`` / ``--scheduler`` (a dask client opened here for the whole command:
    :func:`cluster_client`), progress on stderr. Every command that traces builds it here, once.
    ``in_process``: a command that runs in this process only (``straylight thermal``): ``--workers K``
    is K threads here (as the default local cluster is one process of K threads), no client."""
    threads = getattr(args, "threads", None)
    if threads is not None and threads < 1:
        raise ValueError(f"--threads must be >= 1, got {threads}")
    if in_process:
        workers = getattr(args, "workers", None)
        if workers is not None and workers < 1:
            raise ValueError(f"--workers must be >= 1, got {workers}")
        yield Execution(threads=threads or workers, progress=True)
        return
    with cluster_client(args, in_process_below=in_process_below) as client:
        yield Execution(client=client, threads=threads, progress=True)
