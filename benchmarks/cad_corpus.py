"""Third-party CAD corpus: one row per file (tests/data/cad/THIRD_PARTY.md).

    PYTHONPATH=. python benchmarks/cad_corpus.py [--tolerance-mm 0.05] [--only NAME ...]

Columns: CAD system that wrote the file, cold load (read + tessellate in the child process, empty cache),
cached load (a second process start would pay only this: no child, no OCP import), triangles, the
largest measured chord error (and '!' where refinement stopped short of the tolerance: stalled or
triangle budget), open mesh edges, solids. Each file is loaded in a fresh temporary cache directory.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
import warnings
from pathlib import Path

HERE = Path(__file__).resolve().parents[1] / "tests" / "data" / "cad" / "third_party"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tolerance-mm", type=float, default=0.05)
    parser.add_argument("--only", nargs="*", help="file names to run (default: all)")
    args = parser.parse_args(argv)
    from geometry.io import tessellate_cad

    rows = json.loads((HERE / "corpus.json").read_text())
    if args.only:
        rows = [r for r in rows if r["file"] in set(args.only)]
    print(f"{'file':<34} {'system':<24} {'cold_s':>7} {'cached_s':>8} {'triangles':>9} {'chord_mm':>9} "
          f"{'open':>5} {'solids':>6}")
    total_cold = total_cached = 0.0
    for row in rows:
        with tempfile.TemporaryDirectory() as tmp:
            os.environ["STRAYLIGHT_CACHE"] = "on"
            os.environ["STRAYLIGHT_CACHE_DIR"] = tmp
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                try:
                    start = time.perf_counter()
                    items = tessellate_cad(HERE / row["file"], tolerance_mm=args.tolerance_mm)
                    cold = time.perf_counter() - start
                    start = time.perf_counter()
                    tessellate_cad(HERE / row["file"], tolerance_mm=args.tolerance_mm)
                    cached = time.perf_counter() - start
                except Exception as exc:  # noqa: BLE001 - a row per file, whatever happens
                    print(f"{row['file']:<34} {row['system'][:24]:<24} ERROR {exc}")
                    continue
        reports = [part.meta["tessellation"] for *_, part in items]
        chord = max(r.max_chord_error_mm for r in reports)
        flag = "!" if any(r.stopped for r in reports) else " "
        total_cold += cold
        total_cached += cached
        print(f"{row['file']:<34} {row['system'][:24]:<24} {cold:>7.2f} {cached:>8.3f} "
              f"{sum(r.n_triangles for r in reports):>9d} {chord:>8.4f}{flag} "
              f"{sum(r.n_open_edges for r in reports):>5d} {len(items):>6d}", flush=True)
    print(f"{'total':<34} {'':<24} {total_cold:>7.2f} {total_cached:>8.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
