"""Time to 2 % with a reliable error (VOV <= 0.1) on the Newtonian benchmark, whole command, before and after.

    .venv/bin/python benchmarks/newtonian_pst.py [--quick] [--angles-deg 0 5 10 15 20 30 45 60]
        [--seeds 1 2 3 4 5] [--baseline-angles-deg 10 15 20] [--baseline-seeds 1 2] [--max-seconds 120]
        [--workers K] [--instrument newtonian|guide_scope] [--estimators-after default]
        [--estimators-before baseline ...] [--json OUT.json]

For each angle and seed it runs, as a user would (one process per point, start-up included),

    straylight pst SCENE --angles-deg A --target-rel-error 0.02 --seed S --max-seconds M --out DIR
        [--estimators baseline] [--workers K]

on the Newtonian of ``benchmarks/newtonian.py`` (or, ``--instrument guide_scope``, the refractor with a
lens of ``benchmarks/guide_scope.py``; built once, then read from its cache folder), and
reports wall seconds, CPU seconds of the command (its own and its children's, from
``getrusage(RUSAGE_CHILDREN)``), rays, relative error, VOV and the stop reason from ``pst.json``.
"after" is the default estimator set (or ``--estimators-after NAME``), "before" ``--estimators
baseline`` (the first estimator set; or the sets ``--estimators-before NAME ...``: ``lobes`` is the
default with the engine's roulette threshold; the history sets of benchmarks/estimator_sets.py), in the same run; the table names each set. The
machine is shared: compare CPU seconds and rays; wall time depends on the
neighbours. ``--quick``: seeds 1 2, baseline at 15 and 20 deg, seed 1, capped at 60 s.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ANGLES_DEG = (0, 5, 10, 15, 20, 30, 45, 60)


def _cpu_children() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


#: the commands' compiled modules: kept as an installed package keeps them (pip byte-compiles on install);
#: a machine with PYTHONDONTWRITEBYTECODE set (this one) would otherwise compile ~165 modules from source
#: at every point (~0.3 CPU s) and time that instead of the command
PYCACHE = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "straylight" / "benchmark-pycache"
_warm: set = set()


def _command_env() -> dict:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env["PYTHONPYCACHEPREFIX"] = str(PYCACHE)
    return env


def run_point(scene, angle, seed, estimators, max_seconds, workers, target=0.02) -> dict:
    """One whole ``straylight pst`` command for one angle (``scene``: a scene file, or the command's arguments that
    name one, e.g. ``("--builtin", "tube")``); its times and what pst.json says. The first
    point of a process (per scene and estimator set) is preceded by the same command capped at 2e4 rays,
    untimed: the modules compiled and the kernels' caches written once, as on a machine where straylight
    has run before."""
    exe = [sys.executable, str(HERE / "estimator_sets.py")]  # ``straylight`` with the history sets registered
    env = _command_env()
    scene_args = [str(a) for a in scene] if isinstance(scene, (list, tuple)) else [str(scene)]  # or ("--builtin", "tube")
    if (str(scene), estimators) not in _warm:
        with tempfile.TemporaryDirectory(prefix="newtonian_pst_warm_") as out:
            subprocess.run([*exe, "pst", *scene_args, "--angles-deg", str(angle), "--target-rel-error", "0.5",
                            "--max-rays", "20000", "--out", out, "--estimators", estimators],
                           capture_output=True, text=True, env=env)
        _warm.add((str(scene), estimators))
    with tempfile.TemporaryDirectory(prefix="newtonian_pst_") as out:
        cmd = [*exe, "pst", *scene_args, "--angles-deg", str(angle), "--target-rel-error", str(target),
               "--seed", str(seed), "--max-seconds", str(max_seconds), "--out", out, "--estimators", estimators]
        if workers:
            cmd += ["--workers", str(workers)]
        c0, t0 = _cpu_children(), time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
        wall, cpu = time.perf_counter() - t0, _cpu_children() - c0
        if proc.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd)} failed: {proc.stderr.strip()[-400:]}")
        point = json.loads((Path(out) / "pst.json").read_text())["points"][0]
    rel = point["pst_stderr"] / point["pst"] if point["pst"] else math.nan
    return {"angle_deg": angle, "seed": seed, "estimators": estimators, "wall_s": wall, "cpu_s": cpu,
            "rays": point["rays"], "pst": point["pst"], "rel_error": rel, "vov": point.get("vov"),
            "stop_reason": point.get("stop_reason"), "command": " ".join(["straylight", *cmd[2:4], *cmd[5:]])}


def _median(xs):
    xs = sorted(xs)
    n = len(xs)
    return math.nan if n == 0 else (xs[n // 2] if n % 2 else 0.5 * (xs[n // 2 - 1] + xs[n // 2]))


def table(rows) -> str:
    """Markdown: one line per (angle, estimator set) with medians and ranges over the seeds."""
    out = ["| angle | estimators | seeds | reached 2 % & VOV <= 0.1 | rays (median; range) | wall s (median; max) "
           "| CPU s (median; max) | rel. error | VOV (max) |", "|---|---|---|---|---|---|---|---|---|"]
    keys = sorted({(r["angle_deg"], r["estimators"]) for r in rows}, key=lambda k: (k[0], k[1] == "default", k[1]))
    for a, est in keys:
        sel = [r for r in rows if r["angle_deg"] == a and r["estimators"] == est]
        ok = sum(r["stop_reason"] == "target" for r in sel)
        rays = [r["rays"] for r in sel]
        out.append(f"| {a:g} | {est} | {len(sel)} | {ok}/{len(sel)} "
                   f"| {_median(rays):.3g}; {min(rays):.3g}-{max(rays):.3g} "
                   f"| {_median([r['wall_s'] for r in sel]):.1f}; {max(r['wall_s'] for r in sel):.1f} "
                   f"| {_median([r['cpu_s'] for r in sel]):.1f}; {max(r['cpu_s'] for r in sel):.1f} "
                   f"| {min(r['rel_error'] for r in sel):.2%}-{max(r['rel_error'] for r in sel):.2%} "
                   f"| {max((r['vov'] or 0.0) for r in sel):.3g} |")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--angles-deg", type=float, nargs="+", default=list(ANGLES_DEG))
    ap.add_argument("--seeds", type=int, nargs="+", default=None)
    ap.add_argument("--baseline-angles-deg", type=float, nargs="*", default=None)
    ap.add_argument("--baseline-seeds", type=int, nargs="+", default=None)
    ap.add_argument("--max-seconds", type=float, default=None, help="cap per point (pst --max-seconds)")
    ap.add_argument("--workers", type=int, default=None, help="pst --workers K (default: in-process)")
    ap.add_argument("--instrument", choices=("newtonian", "guide_scope"), default="newtonian")
    ap.add_argument("--estimators-after", default="default", help="the estimator set timed as 'after'")
    ap.add_argument("--estimators-before", nargs="+", default=["baseline"],
                    help="the estimator sets timed as 'before' at --baseline-angles-deg (straylight.analyses.estimators)")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    quick = args.quick
    seeds = args.seeds or ([1, 2] if quick else [1, 2, 3, 4, 5])
    base_angles = args.baseline_angles_deg if args.baseline_angles_deg is not None else ([15, 20] if quick else [10, 15, 20])
    base_seeds = args.baseline_seeds or ([1] if quick else [1, 2])
    max_s = args.max_seconds or (60.0 if quick else 120.0)
    sys.path.insert(0, str(HERE))
    if args.instrument == "guide_scope":
        from guide_scope import build
    else:
        from newtonian import build

    scene = build()
    print(f"scene: {scene}; load {os.getloadavg()[0]:.1f}", file=sys.stderr)
    rows = []
    plan = [(a, s, args.estimators_after) for a in args.angles_deg for s in seeds]
    plan += [(a, s, est) for est in args.estimators_before for a in base_angles for s in base_seeds]
    for a, s, est in plan:
        row = run_point(scene, a, s, est, max_s, args.workers)
        rows.append(row)
        print(f"{a:5g} deg seed {s} {est:8s}: {row['rays']:.3g} rays, {row['wall_s']:.1f} s wall, {row['cpu_s']:.1f} "
              f"CPU s, {row['rel_error']:.2%}, VOV {row['vov'] if row['vov'] is not None else float('nan'):.3g}, "
              f"{row['stop_reason']}", file=sys.stderr, flush=True)
    print(table(rows))
    if args.json:
        Path(args.json).write_text(json.dumps({"scene": str(scene), "rows": rows, "load_end": os.getloadavg()[0]},
                                              indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
