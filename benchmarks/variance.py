"""Variance reduction on the reference tube: next-event estimation (NEE) vs the plain walk.

    .venv/bin/python benchmarks/variance.py [--quick] [--material z302_sample_b] [--json OUT.json]

Both estimators run in this one process, on one core, on the BENCHMARK.md tube (ideal
Lambertian walls of reflectance 0.05 by default), at 10 and 30 deg off axis. For each,
the time to 2 % relative error is extrapolated from one run of wall time t that reached
relative error relerr, t_2% = t (relerr / 0.02)^2 (the 1/sqrt(N) law; t is CPU time,
since the machines are shared and wall time depends on the neighbours), and the ratio
plain / NEE is printed together with the agreement of the two answers in units of
their combined standard error. The engine's estimator ("NEE" below) is what `pst_sweep`
runs by default: at every scatter vertex one shadow ray to a point sampled uniformly over the
detector's area, plus first-vertex area sampling of single-scatter paths combined with the walk
by MIS (docs/engine.md); the plain walk samples the BRDF (cosine) and counts detector hits, with
the same Russian roulette.
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

TARGET = 0.02


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smoke run with few rays")
    parser.add_argument("--material", default=None, help="coating preset (default: BENCHMARK Lambertian 0.05)")
    parser.add_argument("--angles-deg", type=float, nargs="+", default=[10.0, 30.0])
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)

    from materials import Lambertian
    from straylight.analyses.builtin import tube_setup
    import estimator_sets  # noqa: F401 - registers the history sets (benchmarks/estimator_sets.py)
    from straylight.analyses.estimators import estimator_options
    from straylight.analyses.pst import pst_sweep

    setup = tube_setup(material=args.material or Lambertian(rd=0.05))
    rays = {True: 30_000 if args.quick else 400_000, False: 30_000 if args.quick else 2_000_000}
    rows = []
    print(f"{setup.description}; t_2% = t (relerr/0.02)^2, t = CPU time, 1 core")
    print(f"{'a (deg)':>7} {'estimator':>10} {'rays':>9} {'ratio':>12} {'stderr':>9} {'relerr':>7} "
          f"{'cpu t (s)':>9} {'t_2% (s)':>9}")
    for a in args.angles_deg:
        per = {}
        for nee in (True, False):
            t0, c0 = time.perf_counter(), time.process_time()
            res = pst_sweep(setup, np.radians([a]), n_rays=rays[nee], seed=args.seed, nee=nee,
                            options=None if nee else estimator_options("baseline"))  # plain: roulette below 1e-3
            wall, t = time.perf_counter() - t0, time.process_time() - c0
            value, se = float(res.entrance_ratio[0]), float(res.entrance_ratio_stderr[0])
            rel = se / value if value > 0 else math.inf
            t2 = t * (rel / TARGET) ** 2
            per[nee] = {"angle_deg": a, "nee": nee, "rays": rays[nee], "ratio": value, "stderr": se,
                        "relerr": rel, "cpu_seconds": t, "wall_seconds": wall, "t_2pct_s": t2}
            print(f"{a:>7g} {'NEE' if nee else 'plain':>10} {rays[nee]:>9} {value:>12.4e} {se:>9.2e} "
                  f"{rel:>7.2%} {t:>9.2f} {t2:>9.3g}", flush=True)
        z = (per[True]["ratio"] - per[False]["ratio"]) / math.hypot(per[True]["stderr"], per[False]["stderr"])
        gain = per[False]["t_2pct_s"] / per[True]["t_2pct_s"]
        print(f"{'':>7} NEE gain in time to 2 %: {gain:.1f}x; NEE - plain = {z:+.1f} combined sigma")
        rows.append({"angle_deg": a, "nee": per[True], "plain": per[False], "gain": gain, "z": z})
    if args.json:
        args.json.write_text(json.dumps({"description": setup.description, "rows": rows}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
