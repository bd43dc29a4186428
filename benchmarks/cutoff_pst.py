"""The built-in tube at its geometric cut-off, with and without ``direct_area`` (docs/engine.md, "The
unscattered light, exactly").

    .venv/bin/python benchmarks/cutoff_pst.py [--angles-deg 13 14] [--seeds 1 2 3 4] [--max-seconds 30] [--no-write]

Each point is a whole ``straylight pst --builtin tube --angles-deg A --target-rel-error 0.02 --seed S`` command
(one process, start-up included, after one untimed warm-up command per estimator set) with the default set and
with ``walk_direct`` (the default without ``direct_area``: the walk alone meets the beam's straight light).
Printed per point: rays, PST +- error, VOV, why it stopped, CPU and wall seconds. At 14 deg the beam reaches
the detector straight through a sliver (8e-6 of the rays, 17 % of the power): the walk's seeds disagree beyond
their error bars or run to the cap; with the sliver computed they agree. Written to benchmarks/RESULTS.md
(section ``cutoff_pst``).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--angles-deg", type=float, nargs="+", default=[13.0, 14.0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4])
    ap.add_argument("--max-seconds", type=float, default=30.0)
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(HERE))
    from newtonian_pst import run_point

    rows = []
    lines = ["| angle | estimators | seed | rays | PST | rel. error | VOV | stopped by | CPU s | wall s |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for angle in args.angles_deg:
        for seed in args.seeds:
            for est in ("walk_direct", "default"):
                r = run_point(("--builtin", "tube"), angle, seed, est, args.max_seconds, None)
                rows.append(r)
                line = (f"| {angle:g} | {est} | {seed} | {r['rays']:.3g} | {r['pst']:.4e} | "
                        f"{r['rel_error']:.2%} | {r['vov']:.2g} | {r['stop_reason']} | {r['cpu_s']:.1f} | "
                        f"{r['wall_s']:.1f} |")
                lines.append(line)
                print(line, flush=True)
    text = "\n".join(lines)
    from results_md import publish

    publish("cutoff_pst", f"`python benchmarks/cutoff_pst.py`, the built-in tube, whole commands:\n\n{text}",
            write=not args.no_write)
    return 0


if __name__ == "__main__":
    sys.exit(main())
