"""Which paths, and which single rays, carry the variance of a PST point, per estimator set.

    .venv/bin/python benchmarks/variance_paths.py [--scene SCENE.toml | --newtonian | --builtin]
        [--angle-deg 30] [--rays 300000] [--seeds 1 2 3] [--estimators default baseline ...] [--top 8]

For each seed and estimator set (straylight.analyses.estimators), in this one process, it traces the
point as ``pst`` does (the same per-point seed) with path records, and prints:

- the relative error, VOV and CPU seconds of the trace;
- the path families (``paths --group-by family``) ranked by their share of the variance;
- the rays with the largest share of the variance (sum of a ray's records squared over the run's
  sum of squares) and the family of each of their records.

The machine is shared: compare CPU seconds within one run.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def _setup(args):
    if args.builtin:
        from straylight.analyses.builtin import tube_setup

        return tube_setup()
    from straylight.analyses.scene_setup import scene_setup

    if args.newtonian:
        sys.path.insert(0, str(HERE))
        from newtonian import build

        return scene_setup(build())
    return scene_setup(args.scene)


def _family_label(paths, row):
    from straylight.paths import part_family

    events = paths.describe(row)
    return " -> ".join(part_family(p) for p, _ in events) or "(direct)"


def run(setup, angle_deg, seed, estimators, n_rays, top, rr_threshold=None):
    import estimator_sets  # noqa: F401 - registers the history sets (benchmarks/estimator_sets.py)
    from straylight.analyses.estimators import estimator_options
    from straylight.analyses.paths_report import path_report
    from straylight.analyses.precision import reliability
    from straylight.analyses.pst import detector_name, point_seed
    from straylight.trace import OutputOptions, TraceOptions, trace

    det = detector_name(setup.scene, setup.detector)
    opts = replace(estimator_options(estimators, TraceOptions()), output=OutputOptions(record_paths=True, path_depth=8))
    if rr_threshold is not None:
        opts = replace(opts, estimator=replace(opts.estimator, rr_threshold=rr_threshold))
    a = math.radians(angle_deg)
    c0 = time.process_time()
    res = trace(setup.scene, [setup.beam.source(a, 0.0)], n_rays=int(n_rays), seed=point_seed(seed, 0),
                materials=setup.materials, options=opts)
    cpu = time.process_time() - c0
    tally = res.detectors[det]
    rel = reliability(*res.detector_chunks[det], res.n_rays)
    print(f"\n## {angle_deg:g} deg, seed {seed}, {estimators} (rr_threshold {opts.estimator.rr_threshold:g}): {n_rays:.3g} rays, {cpu:.1f} CPU s, "
          f"rel. error {tally.stderr_w / tally.power_w:.2%}, VOV {rel.vov:.3g}, "
          f"largest chunk share {rel.max_chunk_share:.2f}")
    rep = path_report(res.paths, det, tally, group_by="family")
    rows = sorted(rep.rows, key=lambda r: -(r.variance_fraction if r.variance_fraction == r.variance_fraction else 0))
    print("| family | power fraction | share of the variance | records |\n|---|---|---|---|")
    for r in rows[:top]:
        print(f"| {r.label} | {r.fraction:.2%} | {r.variance_fraction:.1%} | {r.n_records} |")
    p = res.paths
    sel = np.flatnonzero(np.asarray(p.detector) == list(p.part_names).index(det))
    ray = np.asarray(p.ray)[sel]
    pw = np.asarray(p.power_w)[sel]
    uniq, inv = np.unique(ray, return_inverse=True)
    x = np.bincount(inv, weights=pw)
    n = res.n_rays
    s1, s2 = x.sum(), (x * x).sum()
    var = s2 - s1 * s1 / n
    order = np.argsort(-x * x)[:top]
    print(f"top rays (share of sum x^2 - S1^2/N = {var:.3g}):")
    for k in order:
        rows_k = sel[inv == k]
        fams = {}
        for rr in rows_k:
            lab = _family_label(p, rr)
            fams[lab] = fams.get(lab, 0.0) + float(p.power_w[rr])
        big = sorted(fams.items(), key=lambda t: -abs(t[1]))[:3]
        desc = "; ".join(f"{lab} ({v / x[k]:.0%})" for lab, v in big)
        print(f"  ray {uniq[k]}: {x[k] * x[k] / var:.1%} of the variance, x = {x[k]:.3g} W "
              f"(mean per ray {s1 / n:.3g}): {desc}")
    return {"seed": seed, "estimators": estimators, "rr": opts.estimator.rr_threshold, "cpu_s": cpu, "segments": res.segments, "rel": tally.stderr_w / tally.power_w,
            "vov": rel.vov, "power_w": tally.power_w}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    src = ap.add_mutually_exclusive_group()
    src.add_argument("--scene")
    src.add_argument("--newtonian", action="store_true")
    src.add_argument("--builtin", action="store_true")
    ap.add_argument("--angle-deg", type=float, default=30.0)
    ap.add_argument("--rays", type=float, default=3e5)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--estimators", nargs="+", default=["default"])
    ap.add_argument("--top", type=int, default=8)
    ap.add_argument("--rr-thresholds", type=float, nargs="+", default=[None],
                    help="Russian roulette thresholds to compare (default: the estimator set's)")
    args = ap.parse_args(argv)
    if not (args.scene or args.newtonian or args.builtin):
        args.newtonian = True
    setup = _setup(args)
    out = []
    for s in args.seeds:
        for est in args.estimators:
            for rr in args.rr_thresholds:
                out.append(run(setup, args.angle_deg, s, est, int(args.rays), args.top, rr))
    print("\n| seed | estimators | rr_threshold | CPU s | segments | rel. error | VOV | CPU s x rel^2 |\n"
          "|---|---|---|---|---|---|---|---|")
    for r in out:
        print(f"| {r['seed']} | {r['estimators']} | {r['rr']:g} | {r['cpu_s']:.1f} | {r['segments']:.3g} | {r['rel']:.2%} "
              f"| {r['vov']:.3g} | {r['cpu_s'] * r['rel'] ** 2 * 1e4:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
