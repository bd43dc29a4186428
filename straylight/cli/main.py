"""The ``straylight`` command: one parser, one module per subcommand group.

straylight's own groups are the modules of ``OWN_GROUPS``; other packages add theirs through entry
points of the group ``straylight.commands`` (the way dask's CLI finds ``distributed``'s commands in
the group ``dask_cli``), as ``rig`` adds ``rig`` from ``rig/cli`` (so straylight never imports rig).
Each module or entry point gives ``add_parser(subparsers)``, which registers its subcommand(s) and
sets ``func`` on them: ``func(args) -> int``. A group that fails to load is an error, not a
silently missing command. Modules import their heavy dependencies inside their commands, so
building the parser stays light (``import straylight`` never pulls in bluesky).
Errors become one line on stderr and exit code 2 (a traceback with ``--debug``).
"""
from __future__ import annotations

import argparse
import importlib
import sys
from contextlib import contextmanager
from importlib.metadata import entry_points

OWN_GROUPS = (
    "straylight.cli.material",
    "straylight.cli.geometry",
    "straylight.cli.trace",
    "straylight.cli.pst",
    "straylight.cli.paths",
    "straylight.cli.critical",
    "straylight.cli.study",
    "straylight.cli.view",
    "straylight.cli.design",
    "straylight.cli.thermal",
)
COMMAND_GROUP = "straylight.commands"  # entry-point group of the command groups of other packages


def command_entry_points() -> list:
    """The installed ``straylight.commands`` entry points, by name."""
    return sorted(entry_points(group=COMMAND_GROUP), key=lambda ep: ep.name)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="straylight",
        description="Stray-light analysis: materials, tracing, baffle studies, reflectometer.",
    )
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in OWN_GROUPS:
        importlib.import_module(name).add_parser(sub)
    for ep in command_entry_points():
        try:
            add_parser = ep.load()
        except Exception as exc:
            raise ImportError(f"straylight command group {ep.name!r} ({ep.value}) failed to load: {exc}") from exc
        add_parser(sub)
    return parser


def _check_requests(args) -> None:
    """Requests that cannot succeed, refused before any work (issue 27), whatever the command: ray
    counts beyond this machine (straylight.budget), chord tolerances that would mesh without bound
    (geometry.limits), and outputs that cannot be written (``--json``/``--png`` files, ``--out``
    folders, ``--report`` folders: atomicio.guard)."""
    from atomicio.guard import check_output_dir, check_output_file

    for flag in ("json", "png"):
        if isinstance(getattr(args, flag, None), str):
            check_output_file(getattr(args, flag), f"--{flag} output")
    for flag in ("out", "report"):
        if isinstance(getattr(args, flag, None), str):
            check_output_dir(getattr(args, flag), f"--{flag} folder")
    for flag in ("rays", "refine_rays"):
        value = getattr(args, flag, None)
        if isinstance(value, int) and value > 0:
            from straylight.budget import check_ray_budget

            check_ray_budget(value, what="--" + flag.replace("_", "-"))
    for flag in ("workers", "threads"):
        value = getattr(args, flag, None)
        if isinstance(value, int) and value > 0 and not getattr(args, "scheduler", None):
            from straylight.budget import check_worker_budget

            check_worker_budget(value, processes=flag == "workers" and bool(getattr(args, "processes", False)),
                                what="--" + flag)
    tolerance = getattr(args, "tolerance_mm", None)
    if isinstance(tolerance, float):
        from geometry.limits import check_tolerance_mm

        check_tolerance_mm(tolerance, "--tolerance-mm")


@contextmanager
def _one_line_warnings():
    """Warnings raised under a command (truncated power, float32 precision, geometry) print as
    ``straylight: warning: ...`` on one line, once per message, instead of Python's two-line form."""
    import warnings

    def show(message, category, filename, lineno, file=None, line=None):
        print(f"straylight: warning: {str(message).strip().splitlines()[0]}", file=file or sys.stderr)

    with warnings.catch_warnings():
        warnings.showwarning = show
        yield


@contextmanager
def _allow_insecure(allowed: bool):
    """``--allow-insecure`` for this command: the sweeps open their dask clients deep inside
    (straylight.engine.backends.dask.dask_client reads STRAYLIGHT_ALLOW_INSECURE_SCHEDULER); restored after."""
    if not allowed:
        yield
        return
    import os

    key = "STRAYLIGHT_ALLOW_INSECURE_SCHEDULER"
    saved = os.environ.get(key)
    os.environ[key] = "1"
    try:
        yield
    finally:
        if saved is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = saved


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 0 if args.command is None else 2
    try:
        _check_requests(args)
        with _allow_insecure(getattr(args, "allow_insecure", False)), _one_line_warnings():
            return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("straylight: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001 - the CLI boundary turns errors into one line
        if args.debug:
            raise
        message = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        print(f"straylight: error: {message}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
