"""What common random numbers buy the vane optimiser (straylight.design.refine).

    .venv/bin/python benchmarks/design_crn.py [--rays 20000] [--seeds 6] [--move-mm 2]

Two layouts of the reference tube (R 50, L 300, S 35, F 0, E 20): the construction A and B = A
with every vane moved up by ``--move-mm``. For each of ``--seeds`` seeds the optimiser's
objective J = mean ln PST over 20, 25, 30 deg is traced for A and B with the same seed (common
random numbers) and for B with an independent seed. Printed: the spread (sample standard
deviation over seeds) of J_A - J_B both ways, and the ratio of the variances, i.e. how many
times more rays independent streams would need to resolve the same difference.
"""
from __future__ import annotations

import argparse
import statistics
import time

from straylight.design import construct_vanes, layout_at, model
from straylight.design.evaluate import log_objective, pst_points
from straylight.execution import Execution


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rays", type=int, default=20_000)
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--move-mm", type=float, default=2.0)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    a = construct_vanes(50, 300, 35, 0, 20)
    b = layout_at(a.spec, [v.z_mm + args.move_mm for v in a.vanes])
    _, _, mats = model.coating("z302_sample_b")
    angles = [20.0, 25.0, 30.0]

    def j(layout, seed):
        return log_objective(pst_points(a.spec, layout.vanes, mats, angles, args.rays, seed,
                                          execution=Execution(threads=args.threads)))

    t0 = time.perf_counter()
    same, indep, se = [], [], []
    for s in range(args.seeds):
        ja, sa = j(a, s)
        jb, _ = j(b, s)
        jb2, _ = j(b, 1000 + s)
        same.append(ja - jb)
        indep.append(ja - jb2)
        se.append(sa)
        print(f"seed {s}: J_A {ja:.3f} +- {sa:.3f}  J_A - J_B same seed {ja - jb:+.3f}  independent {ja - jb2:+.3f}",
              flush=True)
    sd_same, sd_indep = statistics.stdev(same), statistics.stdev(indep)
    print(f"\nspread of J_A - J_B over {args.seeds} seeds ({args.rays} rays/angle, vanes moved {args.move_mm:g} mm):")
    print(f"  common random numbers {sd_same:.4f}   independent streams {sd_indep:.4f}   "
          f"(one J's own stderr ~{statistics.mean(se):.4f})")
    print(f"  variance ratio independent / common = {(sd_indep / sd_same) ** 2:.1f}  "
          f"({time.perf_counter() - t0:.0f} s; the machine is shared)")


if __name__ == "__main__":
    main()
