"""Benchmark scenes written once to a cache folder keyed on their parameters, then reused
(benchmarks/newtonian.py, benchmarks/guide_scope.py)."""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path


def cache_dir(name: str, key: dict) -> Path:
    """``~/.cache/straylight/benchmarks/<name>-<hash of key>`` (``XDG_CACHE_HOME`` honoured)."""
    digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:12]
    root = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "straylight" / "benchmarks"
    return root / f"{name}-{digest}"


def build_once(directory: Path, write, quiet: bool = False) -> Path:
    """``directory/scene.toml``: ``write(tmp)`` fills a fresh folder beside ``directory`` with the scene
    and returns what it built (a phrase, printed with the time unless ``quiet``); the folder then takes
    ``directory``'s name (a crash leaves no half scene behind). An existing scene.toml is returned as it is."""
    import sys
    import time

    scene_toml = directory / "scene.toml"
    if scene_toml.is_file():
        return scene_toml
    t0 = time.perf_counter()
    tmp = directory.with_name(directory.name + f".tmp{os.getpid()}")
    what = write(tmp)
    if not directory.exists():
        tmp.replace(directory)
    if not quiet:
        print(f"built {what} in {time.perf_counter() - t0:.0f} s: {scene_toml}", file=sys.stderr)
    return scene_toml

def main(build, description: str, tolerance_mm: float, argv=None) -> int:
    """The command line of a benchmark scene: ``[--dir DIR] [--tolerance-mm T]``, prints the scene.toml path."""
    import argparse

    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--dir", default=None, help="output folder (default: a cache folder keyed on the parameters)")
    ap.add_argument("--tolerance-mm", type=float, default=tolerance_mm)
    args = ap.parse_args(argv)
    print(build(args.dir, args.tolerance_mm))
    return 0
