"""Do the precision stop's error bars cover the truth? Many seeds per angle against a long reference.

    .venv/bin/python benchmarks/error_coverage.py [--instrument tube|newtonian|guide_scope] [--angles-deg 20 30] [--seeds 16]
        [--target 0.02] [--reference-rays 8000000] [--reference ANGLE=PST,REL_ERR ...] [--estimators default] [--max-seconds S] [--no-write]

For each angle: a reference PST from one long fixed-ray run (its own error, typically 5-10x smaller than
the target), then ``--seeds`` runs with ``precision=Precision(target)`` (the default stop rule of
straylight.stop_rule: minimum sample, confirming look, tail-aware error). Each run's
z = (pst - reference) / sqrt(err^2 + err_ref^2). Printed and written to benchmarks/RESULTS.md: the RMS of
z, the mean z (no bias from the stop: within 2.5 / sqrt(n) of 0), the counts beyond 3 and 4 sigma among
the runs called reliable (stopped by the target), and the median rays and seconds per run. The machine is
shared: seconds are indicative, rays are not.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def _instrument(name: str):
    import straylight.api as sl

    if name == "tube":
        return sl.load(builtin="tube")
    sys.path.insert(0, str(HERE))
    if name == "guide_scope":
        import guide_scope

        return sl.load(str(guide_scope.build(quiet=True)))
    import newtonian

    return sl.load(str(newtonian.build(quiet=True)))  # built once, then read from its cache folder


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--instrument", choices=("tube", "newtonian", "guide_scope"), default="tube")
    ap.add_argument("--angles-deg", type=float, nargs="+", default=[20.0, 30.0])
    ap.add_argument("--seeds", type=int, default=16)
    ap.add_argument("--target", type=float, default=0.02)
    ap.add_argument("--reference-rays", type=int, default=8_000_000)
    ap.add_argument("--no-write", action="store_true", help="print only; leave benchmarks/RESULTS.md alone")
    ap.add_argument("--reference", nargs="+", metavar="ANGLE=PST,REL_ERR", default=None,
                    help="per angle, a reference PST and its relative error to use instead of a long run now (e.g. "
                         "an earlier long run with another estimator set: an independent check of a new one)")
    ap.add_argument("--estimators", default="default", help="the estimator set of the seeded runs")
    ap.add_argument("--max-seconds", type=float, default=math.inf,
                    help="per seeded run (Precision.max_seconds): a run stopped by it is not counted as reliable")
    args = ap.parse_args(argv)
    given = {}
    for item in args.reference or ():
        try:
            angle, values = item.split("=")
            pst, rel = values.split(",")
            given[float(angle)] = (float(pst), float(rel))
        except ValueError:
            ap.error(f"--reference {item!r}: expected ANGLE=PST,REL_ERR (e.g. 30=3.86e-07,0.0087)")
    if given and set(given) != {float(a) for a in args.angles_deg}:
        ap.error("--reference must give a value for every --angles-deg")
    sys.path.insert(0, str(HERE))
    import estimator_sets  # noqa: F401 - registers the history sets for --estimators
    import straylight.api as sl

    inst = _instrument(args.instrument)
    rows = []
    for a in args.angles_deg:
        t0 = time.perf_counter()
        if given:
            r, r_err = given[float(a)][0], given[float(a)][0] * given[float(a)][1]
        else:
            ref = inst.pst([a], rays=args.reference_rays, seed=10_000, estimators=args.estimators)
            r, r_err = float(ref.pst[0]), float(ref.pst_stderr[0])
        t_ref = time.perf_counter() - t0
        z, rays, secs, reliable = [], [], [], []
        for s in range(1, args.seeds + 1):
            t0 = time.perf_counter()
            run = inst.pst([a], seed=s, precision=sl.Precision(args.target, max_seconds=args.max_seconds),
                           estimators=args.estimators)
            secs.append(time.perf_counter() - t0)
            p, e = float(run.pst[0]), float(run.pst_stderr[0])
            z.append((p - r) / math.hypot(e, r_err) if e > 0 else math.nan)
            rays.append(int(run.point_rays[0]) if run.point_rays is not None else run.rays)
            reliable.append((run.diagnostics or [{}])[0].get("stop_reason") == "target")
        z_arr, ok = np.array(z), np.array(reliable)
        zr = z_arr[ok]
        row = {"angle": a, "reference": r, "ref_rel": r_err / r if r else math.nan, "t_ref": t_ref, "n": len(z),
               "reliable": int(ok.sum()), "rms_z": float(np.sqrt(np.nanmean(z_arr ** 2))),
               "mean_z": float(np.nanmean(z_arr)), "beyond3": int(np.sum(np.abs(zr) > 3)),
               "beyond4": int(np.sum(np.abs(zr) > 4)), "rays": float(np.median(rays)), "s": float(np.median(secs))}
        rows.append(row)
        print(f"{args.instrument} {a:g} deg: reference {r:.5g} (+- {row['ref_rel']:.2%}, {t_ref:.0f} s); "
              f"{row['n']} seeds, {row['reliable']} reliable: RMS z {row['rms_z']:.2f}, mean z {row['mean_z']:+.2f} "
              f"(bound +-{2.5 / math.sqrt(row['n']):.2f}), |z|>3 {row['beyond3']}, |z|>4 {row['beyond4']}, "
              f"median {row['rays']:.3g} rays, {row['s']:.1f} s", flush=True)
    if not args.no_write:
        sys.path.insert(0, str(HERE))
        from results_md import write_section

        reference = ("the values given per angle (`--reference`)" if given
                     else f"one run of {args.reference_rays:.0e} rays")
        lines = [f"Instrument `{args.instrument}`, target {args.target:.0%}, {args.seeds} seeds per angle, the "
                 f"default stop rule (straylight.stop_rule), estimator set `{args.estimators}`"
                 f"{'' if math.isinf(args.max_seconds) else f', at most {args.max_seconds:g} s per run'}; reference: {reference}.", "",
                 "| angle (deg) | reference PST (rel. err) | reliable | RMS z | mean z (bound) | abs z > 3 | abs z > 4 "
                 "| median rays | median s |", "|---|---|---|---|---|---|---|---|---|"]
        for r in rows:
            lines.append(f"| {r['angle']:g} | {r['reference']:.5g} ({r['ref_rel']:.2%}) | {r['reliable']}/{r['n']} | "
                         f"{r['rms_z']:.2f} | {r['mean_z']:+.2f} (+-{2.5 / math.sqrt(r['n']):.2f}) | {r['beyond3']} | "
                         f"{r['beyond4']} | {r['rays']:.3g} | {r['s']:.1f} |")
        write_section("error_coverage", "\n".join(lines), name_suffix=args.instrument)
    return 0


if __name__ == "__main__":
    sys.exit(main())
