"""benchmarks/RESULTS.md: generated tables, one section per benchmark script, each dated by the run that
wrote it. A script replaces its own section (between its markers) and leaves the others as they are."""
from __future__ import annotations

import datetime
import subprocess
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "RESULTS.md"
HEADER = ("# Benchmark results (generated)\n\nEach section is written by the script it names; rerun the script to "
          "refresh it. Do not edit by hand.\n")


def write_section(name: str, body: str, path: Path = RESULTS, name_suffix: str = "") -> Path:
    """Replace (or add) the section of benchmark ``name`` with ``body`` (markdown), dated and with the commit."""
    import atomicio

    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                                cwd=path.parent, timeout=10).stdout.strip() or "?"
    except (OSError, subprocess.SubprocessError):
        commit = "?"
    stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    title = f"{name} ({name_suffix})" if name_suffix else name
    begin, end = f"<!-- begin {title} -->", f"<!-- end {title} -->"
    section = f"{begin}\n## {title}\n\n_{stamp}, commit {commit}, `python benchmarks/{name}.py`_\n\n{body.strip()}\n{end}"
    text = path.read_text(encoding="utf-8") if path.exists() else HEADER
    if begin in text and end in text:
        a, b = text.index(begin), text.index(end) + len(end)
        text = text[:a] + section + text[b:]
    else:
        text = text.rstrip() + "\n\n" + section + "\n"
    atomicio.write_text(path, text)
    return path


def publish(name: str, text: str, write: bool = True, name_suffix: str = "") -> None:
    """Print a benchmark's table and, unless ``write`` is false (``--no-write``), put it in its section."""
    print(text, flush=True)
    if write:
        write_section(name, text, name_suffix=name_suffix)
