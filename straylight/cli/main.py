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
import math
import os
import sys
from contextlib import contextmanager

from straylight.cli.long_lived import long_lived_objects

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
    "straylight.cli.optics",
    "straylight.cli.ghosts",
)
COMMAND_GROUP = "straylight.commands"  # entry-point group of the command groups of other packages
GROUP_OF_COMMAND = {"material": "straylight.cli.material", "geometry": "straylight.cli.geometry",
                    "trace": "straylight.cli.trace", "pst": "straylight.cli.pst", "paths": "straylight.cli.paths",
                    "critical": "straylight.cli.critical", "study": "straylight.cli.study", "view": "straylight.cli.view",
                    "design": "straylight.cli.design", "thermal": "straylight.cli.thermal",
                    "exchange": "straylight.cli.thermal", "optics": "straylight.cli.optics",
                    "ghosts": "straylight.cli.ghosts"}
"""The module of ``OWN_GROUPS`` that registers each of straylight's own commands: a command's run builds only its
own group's parser (:func:`build_parser`); tests/straylight/test_cli_first_hour.py checks the table against the
modules."""


def command_entry_points() -> list:
    """The installed ``straylight.commands`` entry points, by name (importlib.metadata, ~0.02 CPU s to import,
    only when a command other than straylight's own is asked for)."""
    from importlib.metadata import entry_points

    return sorted(entry_points(group=COMMAND_GROUP), key=lambda ep: ep.name)


class _Parser(argparse.ArgumentParser):
    """argparse with a suggestion for a mistyped flag (``--rayz`` -> did you mean ``--rays``?), as Python
    3.14's ``suggest_on_error`` does for choices; here by difflib over the parser's own option strings."""

    def error(self, message):
        import difflib

        if "unrecognized arguments:" in message:
            options = _option_strings(self)
            hints = []
            for word in message.split("unrecognized arguments:", 1)[1].split():
                if word.startswith("-"):
                    close = difflib.get_close_matches(word.split("=", 1)[0], sorted(set(options)), n=1, cutoff=0.6)
                    if close:
                        hints.append(f"{word}: did you mean {close[0]}?")
            if hints:
                message += " (" + "; ".join(hints) + ")"
        super().error(message)


def _option_strings(parser) -> list:
    """Every option string of ``parser`` and of its subcommands, at any depth."""
    out = []
    for action in parser._actions:
        out += action.option_strings
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                out += _option_strings(sub)
    return out


class _VersionAction(argparse.Action):
    """``--version``: print ``straylight VERSION`` and exit, as argparse's ``version`` action, the version read
    (importlib.metadata, ~3 ms) only when asked for, not each time the parser is built."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS,
                 help="show program's version number and exit"):
        super().__init__(option_strings=option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        parser._print_message(f"straylight {_version()}\n", sys.stdout)
        parser.exit()


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("straylight")
    except Exception:  # noqa: BLE001 - a source checkout without an install
        return "unknown (not installed)"


RAY_COUNT_FLAGS = ("rays", "trace_rays", "refine_rays")


def ray_count(text: str) -> int:
    """A ray count as people write it: 100000, 100_000, 1e5 (a whole number)."""
    try:
        value = float(str(text).replace("_", ""))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number of rays (100000, 1e5), got {text!r}") from None
    import math

    if not math.isfinite(value) or value != int(value):
        raise argparse.ArgumentTypeError(f"expected a whole number of rays (100000, 1e5), got {text!r}")
    return int(value)


def _ray_counts_as_numbers(parser) -> None:
    """Every ``--rays``-like flag of every subcommand reads 1e5 as well as 100000."""
    for action in parser._actions:
        if action.dest in RAY_COUNT_FLAGS and action.type is int:
            action.type = ray_count
        for sub in action.choices.values() if isinstance(action, argparse._SubParsersAction) else ():
            _ray_counts_as_numbers(sub)


REFERENCE_PAGES = {"1": "conventions.md", "2": "scan-csv.md", "3": "effects.md", "4": "commands.md",
                   "5": "material.md", "6": "scene.md", "7": "scene.md", "8": "commands.md"}
"""The page of docs/reference/ that says, in the project's own words, what a section of the specification says."""


def reference_page(text: str) -> str:
    """``text`` with every "CONTRACTS section N" / "CONTRACTS §N.M" pointing at the project's own reference page
    (docs/reference/), which users have; the specification itself is not shipped."""
    import re

    def page(match):
        return "docs/reference/" + REFERENCE_PAGES.get(match.group(1), "README.md")

    return re.sub(r"CONTRACTS\s*(?:section\s*)?§?\s*(\d+)(?:\.\d+)*", page, text)


def plain_help(text):
    """A help text as the terminal shows it: no reST markup (``name`` -> name), references to docs/reference/."""
    if not text or text is argparse.SUPPRESS:
        return text
    return reference_page(text.replace("``", "").replace("`", ""))


def _plain_texts(parser) -> None:
    """Every description and help text of ``parser`` and its subcommands through :func:`plain_help`."""
    parser.description = plain_help(parser.description)
    parser.epilog = plain_help(parser.epilog)
    for action in parser._actions:
        action.help = plain_help(action.help)
        if isinstance(action, argparse._SubParsersAction):
            for choice in action._choices_actions:
                choice.help = plain_help(choice.help)
            for sub in action.choices.values():
                _plain_texts(sub)


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``straylight`` parser, every command's; with ``command`` one of straylight's own
    (:data:`GROUP_OF_COMMAND`), only that command's group (the same subparser: the other groups' modules and
    the entry points, ~0.03 CPU s, are not imported for it)."""
    parser = _Parser(
        prog="straylight",
        description="Stray-light analysis: materials, tracing, baffle studies, reflectometer. "
                    "Formats and commands: docs/reference/ in the project.",
    )
    parser.add_argument("--version", action=_VersionAction)
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors (also after the command)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    own = GROUP_OF_COMMAND.get(command) if command is not None else None
    for name in OWN_GROUPS if own is None else (own,):
        importlib.import_module(name).add_parser(sub)
    for ep in command_entry_points() if own is None else ():
        try:
            add_parser = ep.load()
        except Exception as exc:
            raise ImportError(f"straylight command group {ep.name!r} ({ep.value}) failed to load: {exc}") from exc
        add_parser(sub)
    _ray_counts_as_numbers(parser)
    _force_flags(parser)
    _plain_texts(parser)
    return parser


def _force_flags(parser) -> None:
    """Every command that writes an output file takes ``--force`` (replace an existing output file): without
    it, an existing file is refused before any work (docs/reference/commands.md, "Outputs")."""
    outs = set(OUTPUT_FILE_FLAGS) | {"output"}
    for action in parser._actions:
        for sub in action.choices.values() if isinstance(action, argparse._SubParsersAction) else ():
            dests = {a.dest for a in sub._actions}
            if dests & outs and "force" not in dests:
                sub.add_argument("--force", action="store_true",
                                 help="replace output files that exist already (a run may always replace its own "
                                      "unchanged outputs)")
            _force_flags(sub)


def _check_requests(args) -> None:
    """Requests that cannot succeed, refused before any work, whatever the command: ray
    counts beyond this machine (straylight.budget), chord tolerances that would mesh without bound
    (geometry.limits), and outputs that cannot be written (``--json``/``--png`` files, ``--out``
    folders, ``--report`` folders: atomicio.guard)."""
    from atomicio.guard import check_output_dir, check_output_file
    import os

    from atomicio.output_rule import check_not_an_input, check_plain_path
    from atomicio.written_outputs import replaceable

    files, folders = _outputs(args)
    inputs = _input_files(args)
    for flag, path in files:
        check_plain_path(path, f"{flag} output")
        check_not_an_input(path, inputs, f"{flag} output")
        check_output_file(path, f"{flag} output")
        if not getattr(args, "force", False) and not _appends(args, flag) and os.path.isfile(path) \
                and not replaceable(path):
            raise ValueError(f"{path}: the {flag} output exists already and this command did not write it (or it "
                             "changed since); give --force to replace it, or another path")
    for flag, path in folders:
        check_plain_path(path, f"{flag} folder")
        check_output_dir(path, f"{flag} folder")
    for flag in RAY_COUNT_FLAGS:
        value = getattr(args, flag, None)
        none_ok = args.command == "view" and flag == "rays"  # view --rays 0: draw no ray
        if isinstance(value, int) and not isinstance(value, bool) and (value < 0 or (value == 0 and not none_ok)):
            raise ValueError(f"--{flag.replace('_', '-')} must be >= 1, got {value}")
        if isinstance(value, int) and value > 0:
            from straylight.budget import check_ray_budget

            check_ray_budget(value, what="--" + flag.replace("_", "-"))
    for flag in ("workers", "threads"):
        value = getattr(args, flag, None)
        if isinstance(value, int) and value > 0 and not getattr(args, "scheduler", None):
            from straylight.budget import check_worker_budget

            check_worker_budget(value, processes=flag == "workers" and bool(getattr(args, "processes", False)),
                                what="--" + flag)
    for flag in ("angle_deg", "angles_deg"):  # off-axis angles of the beam: in (-90, 90) deg
        values = getattr(args, flag, None)
        for value in values if isinstance(values, list) else [values] if isinstance(values, float) else []:
            if not -90 < value < 90:
                raise ValueError(f"--{flag.replace('_', '-')} must be in (-90, 90) deg (off-axis angles of the beam), "
                                 f"got {value:g}")
    for value in getattr(args, "azimuths_deg", None) or []:  # turns of the tilt about the axis
        if isinstance(value, float) and not math.isfinite(value):
            raise ValueError(f"--azimuths-deg must be finite numbers, got {value:g}")
    tolerance = getattr(args, "tolerance_mm", None)
    if isinstance(tolerance, float):
        from geometry.limits import check_tolerance_mm

        check_tolerance_mm(tolerance, "--tolerance-mm")


OUTPUT_FILE_FLAGS = ("json", "png", "plot", "csv", "html")
OUTPUT_DIR_FLAGS = ("out", "report")


def _remember_outputs(files) -> None:
    """Record the output files this run wrote (atomicio.written_outputs): a rerun may replace them."""
    import os

    from atomicio.written_outputs import remember

    for _, path in files:
        if os.path.isfile(path):
            remember(path)


def _appends(args, flag: str) -> bool:
    """The command adds to this output rather than replacing it (``rig scan --resume -o SCAN.csv``)."""
    return flag == "-o/--output" and bool(getattr(args, "resume", False))


def _outputs(args) -> tuple[list, list]:
    """([(flag, file path)], [(flag, folder path)]) of the outputs this command will write."""
    files = [(f"--{f}", getattr(args, f)) for f in OUTPUT_FILE_FLAGS if isinstance(getattr(args, f, None), str)]
    folders = [(f"--{f}", getattr(args, f)) for f in OUTPUT_DIR_FLAGS if isinstance(getattr(args, f, None), str)]
    out = getattr(args, "output", None)
    if isinstance(out, str):  # -o: a file (MODEL.json, SCAN.csv, SCENE.toml) or a folder (geometry build)
        from pathlib import Path

        p = Path(out)
        (folders if p.is_dir() or not p.suffix else files).append(("-o/--output", out))
    return files, folders


def _input_files(args) -> list:
    """Every argument that names an existing regular file and is not an output: the command's inputs."""
    import os

    outs = set(OUTPUT_FILE_FLAGS) | set(OUTPUT_DIR_FLAGS) | {"output"}
    found = []
    for key, value in vars(args).items():
        if key in outs or key == "func":
            continue
        for v in value if isinstance(value, (list, tuple)) else [value]:
            if isinstance(v, str) and v and "\0" not in v:
                try:
                    if os.path.isfile(v):
                        found.append(v)
                except (OSError, ValueError):
                    continue
    return found


def _numba_for_command_line(args) -> None:
    """A command that traces starts numba without its cffi support and its LLVM-lock events
    (materials.jit_start.for_command_line: ~0.05 CPU s; nothing in a straylight command calls cffi from
    jitted code or reads numba's compile timers)."""
    from straylight.compile_notice import TRACING_COMMANDS

    if args.command in TRACING_COMMANDS:
        from materials.jit_start import for_command_line

        for_command_line()


def _announce_first_compile(args) -> None:
    """Say so when this run compiles the tracer's kernels (straylight.compile_notice)."""
    from straylight.compile_notice import TRACING_COMMANDS, first_compile_notice

    if args.command in TRACING_COMMANDS:
        notice = first_compile_notice()
        if notice:
            print(f"straylight: {notice}", file=sys.stderr, flush=True)


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


def _interrupted(exc: BaseException | None) -> bool:
    """Was ``exc`` caused by Ctrl-C? A KeyboardInterrupt raised inside a compiled (numba) kernel comes
    out as ``SystemError: CPUDispatcher(...) returned a result with an exception set`` whose context
    is the KeyboardInterrupt."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


def _disk_full_message(exc: BaseException | None) -> str | None:
    """A full disk, said with the folder to free: "[Errno 28] No space left on device" from a cache
    write (numba's kernels, tessellations, tables) named no file and failed every command."""
    import errno
    import os

    seen = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, getattr(errno, "EDQUOT", errno.ENOSPC)):
            break
        exc = exc.__cause__ or exc.__context__
    else:
        return None
    if not isinstance(exc, OSError):
        return None
    name = exc.filename
    found: list[str | None] = [os.environ.get("STRAYLIGHT_CACHE_DIR"), os.environ.get("NUMBA_CACHE_DIR")]
    try:
        from atomicio.cache_dirs import user_cache_root

        found.append(str(user_cache_root()))
    except Exception:  # noqa: BLE001 - naming the folder must not fail in turn
        pass
    caches: list[str] = list(dict.fromkeys(c for c in found if c))
    in_cache = name is None or any(str(name).startswith(c) for c in caches)
    if in_cache and caches:
        return (f"no space left on the disk of the cache folder {' or '.join(caches) if name is None else name} "
                f"({exc.strerror}): free space there, or point STRAYLIGHT_CACHE_DIR and NUMBA_CACHE_DIR at "
                f"another disk, or set STRAYLIGHT_CACHE=off")
    return f"no space left on the disk holding {name} ({exc.strerror}): free space there or write elsewhere"


#: the BLAS libraries' own thread pools, kept to one thread in the command (:func:`single_threaded_blas`)
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS", "VECLIB_MAXIMUM_THREADS")


def single_threaded_blas() -> None:
    """One BLAS thread for the command, unless the environment names a count (read when numpy loads its BLAS,
    so only before numpy's import; worker processes inherit it). The command's parallelism is its batches
    (``--workers``); its BLAS calls are products of (n, 3) arrays, and OpenBLAS's idle worker spins after each
    of them: 0.2 of a 4.2 CPU s ``pst`` point on the guide scope (benchmarks/RESULTS.md), more beside other
    workers on a busy machine."""
    if "numpy" in sys.modules:
        return
    for name in BLAS_THREAD_VARIABLES:
        os.environ.setdefault(name, "1")


def main(argv=None) -> int:
    """The ``straylight`` command. Ctrl-C (SIGINT) is honoured from the first instant, while the
    parser imports its groups as well as during the command: one line, exit 130."""
    single_threaded_blas()
    _no_collection_at_exit()
    with _sigint_kept():
        try:
            return _main(argv)
        except KeyboardInterrupt:
            print("straylight: interrupted", file=sys.stderr)
            return 130


@contextmanager
def _rarer_full_collections(every: int = 100):
    """CPython's full garbage collections at most once per ``every`` collections of the middle generation
    (default 10) during the command; restored after.

    A command imports numba and matplotlib on its way (some 10^5 objects, modules, functions and classes that
    live as long as the process); with the default, full collections ran three times over them during a
    ``straylight pst`` run, 0.12 CPU s, and found nothing to free. The young generations are collected as
    often as before, so short-lived reference cycles go as soon as they did; CPython's own rule (a full
    collection only once the objects added since the last one are a quarter of the old ones) still applies."""
    import gc

    saved = gc.get_threshold()
    gc.set_threshold(saved[0], saved[1], max(saved[2], every))
    try:
        yield
    finally:
        gc.set_threshold(*saved)


_EXIT_HOOK: list = []


def _no_collection_at_exit() -> None:
    """Skip the garbage collections of the interpreter's shutdown (once per process).

    At exit CPython tears the modules down and runs full collections over every object it tracks: after
    a command that loaded numba's typing registries and matplotlib's artists, a third of a CPU second
    (measured on ``straylight pst``, a tenth of a short command) spent freeing memory the operating system
    takes back anyway. ``gc.freeze()`` in an atexit handler moves those objects out of the collector's
    sight. Registered first, it runs after the atexit handlers of the libraries the command imports (dask,
    numba, tempfile), which do not rely on the collector. What is given up: ``__del__`` of objects left
    in reference cycles at exit, which Python does not promise to call anyway (the language reference,
    ``object.__del__``); outputs are written and closed before exit (atomicio)."""
    if _EXIT_HOOK:
        return
    import atexit
    import gc

    atexit.register(gc.freeze)
    _EXIT_HOOK.append(True)


@contextmanager
def _sigint_kept():
    """A Ctrl-C is never lost. Python raises KeyboardInterrupt at the next bytecode, which may be inside
    a C callback (numba's LLVM object-cache hook while kernels load) that swallows it with an "Exception
    ignored" message. Such a swallowed KeyboardInterrupt prints nothing here, and SIGINT is sent again
    0.2 s later (once per swallowed one), so the interrupt reaches this command."""
    import os
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    state = {"done": False}

    def resend():
        if not state["done"]:
            os.kill(os.getpid(), signal.SIGINT)

    previous_hook = sys.unraisablehook

    def quiet(unraisable):
        if isinstance(unraisable.exc_value, KeyboardInterrupt):
            timer = threading.Timer(0.2, resend)
            timer.daemon = True
            timer.start()
            return
        previous_hook(unraisable)

    sys.unraisablehook = quiet
    try:
        yield
    finally:
        state["done"] = True
        sys.unraisablehook = previous_hook


def _command_word(argv) -> str | None:
    """The command ``argv`` names: its first word, unless that is an option (``-h``, ``--version``: straylight's
    own options come before the command and take no value)."""
    return argv[0] if argv and not argv[0].startswith("-") else None


def _with_scene_file(exc, args, message: str) -> str:
    """A trace's refusal of the scene it was given (a TraceError: diffraction without a wavelength, coatings
    under two wavelengths...) names the scene file it came from when the message does not already."""
    from straylight.engine.options import TraceError

    scene = getattr(args, "scene", None)
    if isinstance(exc, TraceError) and isinstance(scene, str) and scene and scene not in message:
        return f"{scene}: {message}"
    return message


def _main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv  # anywhere: `straylight pst ... --debug` as well as `straylight --debug pst ...`
    argv = [a for a in argv if a != "--debug"]
    with long_lived_objects("parser"):  # the parser and the modules its groups import
        parser = build_parser(_command_word(argv))
        args = parser.parse_args(argv)
    args.debug = debug
    if not getattr(args, "func", None):
        parser.print_help()
        return 0 if args.command is None else 2
    try:
        _check_requests(args)
        _numba_for_command_line(args)
        _announce_first_compile(args)
        from atomicio.output_rule import outputs_held

        files, folders = _outputs(args)
        with _allow_insecure(getattr(args, "allow_insecure", False)), _one_line_warnings(), _rarer_full_collections(), \
                outputs_held(folders=[(p, f"{f} folder") for f, p in folders],
                             files=[(p, f"{f} output") for f, p in files if f == "-o/--output"]):
            try:
                return int(args.func(args) or 0)
            finally:
                _remember_outputs(files)
    except KeyboardInterrupt:
        print("straylight: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001 - the CLI boundary turns errors into one line
        if _interrupted(exc):
            print("straylight: interrupted", file=sys.stderr)
            return 130
        if args.debug:
            raise
        message = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        message = _disk_full_message(exc) or message
        message = _with_scene_file(exc, args, message)
        print(f"straylight: error: {message}", file=sys.stderr)
        del exc
        # what the failed command built, left in reference cycles through the traceback's frames, is freed now,
        # while the libraries it holds are alive: an embree scene freed at the interpreter's teardown aborted the
        # process ("pure virtual method called", exit 134) after a one-line refusal of `ghosts` (poke's PLOS
        # Cassegrain)
        import gc

        gc.collect()
        return 2


if __name__ == "__main__":
    sys.exit(main())
