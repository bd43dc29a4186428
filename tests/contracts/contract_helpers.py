"""Helpers for the contract-conformance checks (CONTRACTS.md as an outside checker reads it).

Inputs are generated here, never taken from the project's own test data.
"""
import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
CONSOLE = Path(sys.executable).parent / "straylight"


def run_cli(argv, capsys):
    """In-process ``straylight`` call: (exit code, stdout, stderr)."""
    from straylight.cli.main import main

    try:
        rc = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse errors and --help
        rc = exc.code if isinstance(exc.code, int) else 2
    out, err = capsys.readouterr()
    return rc, out, err


def run_console(argv, timeout=120, cwd=None, **kwargs):
    """The installed console script in a subprocess."""
    exe = str(CONSOLE) if CONSOLE.exists() else None
    cmd = [exe] if exe else [sys.executable, "-m", "straylight.cli.main"]
    env = dict(os.environ, MPLBACKEND="Agg")
    return subprocess.run(cmd + [str(a) for a in argv], capture_output=True, text=True, timeout=timeout,
                          cwd=cwd, env=env, **kwargs)


def assert_one_line_error(rc, err, *needles):
    """Non-zero exit, exactly one non-empty stderr line, no traceback, naming every needle."""
    assert rc != 0, err
    lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith("straylight: warning")]
    assert len(lines) == 1, f"expected one error line, got:\n{err}"
    assert "Traceback" not in err
    for needle in needles:
        assert str(needle) in lines[0], f"{needle!r} not in {lines[0]!r}"
    return lines[0]


def write_json(path, data):
    path = Path(path)
    path.write_text(json.dumps(data), encoding="utf-8")
    return path

