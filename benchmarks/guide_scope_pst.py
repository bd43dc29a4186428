"""The guide scope with its lens at every angle to 2 % (VOV <= 0.1), in reference CPU seconds.

    .venv/bin/python benchmarks/guide_scope_pst.py [--angles-deg 0 5 10 15 20 30 45 60] [--seeds 1 2]
        [--before reflections] [--before-angles-deg 5 10] [--before-seeds 1] [--max-seconds 60] [--no-write]

Each point is a whole ``straylight pst SCENE --angles-deg A --target-rel-error 0.02 --seed S`` command
(benchmarks/newtonian_pst.py's ``run_point``: start-up included, one process per point, the modules
byte-compiled as an installed package has them) on the guide scope
of ``benchmarks/guide_scope.py``, with the default estimator set ("after") and, at ``--before-angles-deg``,
the set ``--before`` (``reflections``: the default before the thick mirrors, specular NEE through single
reflections only; ``reverse``: without specular NEE; ``entrance``: without reverse chains either;
benchmarks/estimator_sets.py) in the same run.

**Reference CPU seconds** (/work's BENCHMARK normalisation, by raw embreex): the command's CPU seconds
times r / 3.3e6, where r is raw embreex's first-hit rate per CPU second, 1 process, on 1e6 incoherent rays
in the reference baffled tube (``benchmarks/throughput.py``'s ``raw_rates``; 3.3 M/s on the reference
machine), measured before and after the points (the mean is used; both printed). A machine (or a moment
of shared load) slower than the reference then counts its seconds as fewer. Written to
benchmarks/RESULTS.md (section ``guide_scope_pst``) with the load average.
"""
from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
REFERENCE_RAW_RATE = 3.3e6  # raw embreex, incoherent rays, 1 process, on the reference machine (intersections/s)


def raw_rate_cpu() -> float:
    """Raw embreex first hits per CPU second on the reference tube (the best of 3)."""
    from geometry.scenes import reference_scene
    from throughput import raw_rates

    scene = reference_scene(tolerance_mm=0.01)
    return max(raw_rates(scene)[2] for _ in range(3))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--angles-deg", type=float, nargs="+", default=[0, 5, 10, 15, 20, 30, 45, 60])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--before", default="reflections")
    ap.add_argument("--before-angles-deg", type=float, nargs="*", default=[5, 10])
    ap.add_argument("--before-seeds", type=int, nargs="+", default=[1])
    ap.add_argument("--max-seconds", type=float, default=60.0)
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(HERE))
    from guide_scope import build
    from newtonian_pst import run_point

    scene = build(quiet=True)
    load0 = os.getloadavg()[0]
    raw0 = raw_rate_cpu()
    print(f"scene {scene}; load {load0:.1f}; raw embreex {raw0 / 1e6:.2f} M/CPU-s", file=sys.stderr, flush=True)
    rows = []
    plan = [(a, s, "default") for a in args.angles_deg for s in args.seeds]
    plan += [(a, s, args.before) for a in args.before_angles_deg for s in args.before_seeds]
    for a, s, est in plan:
        row = run_point(scene, a, s, est, args.max_seconds, None)
        rows.append(row)
        print(f"{a:5g} deg seed {s} {est:8s}: {row['rays']:.3g} rays, {row['cpu_s']:.1f} CPU s, {row['rel_error']:.2%}, "
              f"VOV {row['vov'] if row['vov'] is not None else math.nan:.3g}, {row['stop_reason']}, PST {row['pst']:.4g}",
              file=sys.stderr, flush=True)
    raw1 = raw_rate_cpu()
    load1 = os.getloadavg()[0]
    scale = 0.5 * (raw0 + raw1) / REFERENCE_RAW_RATE
    lines = [f"Guide scope (`benchmarks/guide_scope.py`), whole `straylight pst --target-rel-error 0.02` command per "
             f"point, max {args.max_seconds:g} s; raw embreex {raw0 / 1e6:.2f} / {raw1 / 1e6:.2f} M/CPU-s before / after "
             f"(reference 3.3): reference CPU s = CPU s x {scale:.2f}; load average {load0:.1f} / {load1:.1f} (shared "
             f"machine); modules byte-compiled as an installed package has them (one untimed warm-up command first; "
             f"benchmarks/newtonian_pst.py `run_point`). `default` includes entrance sampling, reverse chains, "
             f"tree_split, the trees' end draws (tree_ends) and specular NEE through single reflections and thick "
             f"mirrors; `{args.before}` is another set "
             f"(benchmarks/estimator_sets.py).", "",
             "| angle | estimators | seed | reached 2 % & VOV <= 0.1 | rays | CPU s | reference CPU s | rel. error | VOV "
             "| PST |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in sorted(rows, key=lambda r: (r["angle_deg"], r["estimators"] != "default", r["seed"])):
        lines.append(f"| {r['angle_deg']:g} | {r['estimators']} | {r['seed']} | "
                     f"{'yes' if r['stop_reason'] == 'target' else 'no (' + str(r['stop_reason']) + ')'} | "
                     f"{r['rays']:.3g} | {r['cpu_s']:.1f} | {r['cpu_s'] * scale:.1f} | {r['rel_error']:.2%} | "
                     f"{r['vov'] if r['vov'] is not None else math.nan:.3g} | {r['pst']:.4g} |")
    from results_md import publish

    publish("guide_scope_pst", "\n".join(lines), write=not args.no_write)
    return 0


if __name__ == "__main__":
    sys.exit(main())
