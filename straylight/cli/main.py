"""The ``straylight`` command: one parser, one module per subcommand group.

Each module in ``SUBCOMMAND_MODULES`` exposes ``add_parser(subparsers)``, which
registers its subcommand(s) and sets ``func`` on them: ``func(args) -> int``.
Modules are imported lazily so ``import straylight`` never pulls in bluesky.
Errors become one line on stderr and exit code 2 (a traceback with ``--debug``).
"""
from __future__ import annotations

import argparse
import importlib
import sys

SUBCOMMAND_MODULES = (
    "straylight.cli.material",
    "straylight.cli.geometry",
    "straylight.cli.trace",
    "straylight.cli.pst",
    "straylight.cli.paths",
    "straylight.cli.critical",
    "straylight.cli.study",
    "straylight.cli.view",
    "straylight.cli.rig",
)


class CliError(Exception):
    """A user-facing error: printed as one line, exit code 2."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="straylight",
        description="Stray-light analysis: materials, tracing, baffle studies, reflectometer.",
    )
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in SUBCOMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:  # that subcommand group is not written yet
                continue
            raise
        module.add_parser(sub)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 0 if args.command is None else 2
    try:
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
