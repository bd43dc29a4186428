"""Vane optimiser against the Freniere construction at equal vane count (straylight.design.optimise).

    .venv/bin/python benchmarks/vane_optimiser.py [--rays 3000] [--evals 20] [--check-rays 30000] [--no-write]

Reference tube R 50, L 300, S 35 mm, F 0, E 20 deg, z302 coating, 1 mm vanes. The optimiser
(positions, bevel angle and side; common random numbers at ``--rays`` per angle) starts from the
Freniere construction. Both designs are then re-traced independently (fresh seeds, not the
optimiser's) at ``--check-rays`` per angle over E, E + 5, E + 10 deg, and the ratio of the mean
PST over the band (Freniere / optimised) is printed with its 1-sigma error and written to
benchmarks/RESULTS.md. Short runs: the machine is shared, the numbers are measured under load.
"""
from __future__ import annotations

import argparse
import math
import time

from straylight.design import construct_vanes, model
from straylight.design.evaluate import pst_points
from straylight.design.optimise import optimise_vanes
from straylight.execution import Execution


def band_mean(points):
    n = len(points)
    return sum(p.pst for p in points) / n, math.sqrt(sum(p.pst_stderr ** 2 for p in points)) / n


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rays", type=int, default=3000)
    ap.add_argument("--evals", type=int, default=20)
    ap.add_argument("--check-rays", type=int, default=30000)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--bevel-deg", type=float, default=45.0, help="the Freniere design's own bevel (back side)")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    ex = Execution(threads=args.threads)
    built = construct_vanes(50, 300, 35, 0, 20, bevel_deg=args.bevel_deg)  # the Freniere start, knife-edged
    spec = built.spec
    _, _, mats = model.coating("z302_sample_b")
    angles = [20.0, 25.0, 30.0]
    t0 = time.perf_counter()
    res = optimise_vanes(spec, mats, angles, rays=args.rays, seed=11, max_evals=args.evals, execution=ex)
    t_opt = time.perf_counter() - t0
    check_seed = 90210  # fresh: not the optimiser's seed 11; shared by the two designs (CRN re-trace)
    fre = pst_points(spec, built.vanes, mats, angles, args.check_rays, check_seed, execution=ex)
    s = res.spec
    opt = pst_points(s, [s.vane_at(z) for z in res.z_mm], mats, angles, args.check_rays, check_seed, execution=ex)
    bare = pst_points(spec, [], mats, angles, args.check_rays, check_seed + 2, execution=ex)
    square = construct_vanes(50, 300, 35, 0, 20)  # the same construction with square (unbevelled) edges
    sq = pst_points(square.spec, square.vanes, mats, angles, args.check_rays, check_seed + 3, execution=ex)
    (mf, ef), (mo, eo), (mb, eb), (ms, es) = band_mean(fre), band_mean(opt), band_mean(bare), band_mean(sq)
    ratio = mf / mo if mo > 0 else math.inf
    ratio_se = ratio * math.hypot(ef / mf, eo / mo) if mo > 0 and mf > 0 else math.nan
    lines = [f"Reference tube R 50, L 300, S 35 mm, F 0, E 20 deg, z302, {len(built.vanes)} vanes (equal count). "
             f"Optimiser: {args.rays} rays/angle CRN, {args.evals} layouts per z refinement, {t_opt:.0f} s. "
             f"Independent re-trace: {args.check_rays} rays/angle, a fresh seed (not the optimiser's) shared by both designs; errors propagated as if independent (conservative). Measured under load from parallel "
             "work (2 shared cores): short runs.", "",
             "| design | bevel | mean PST over 20, 25, 30 deg | 1-sigma |", "|---|---|---|---|",
             f"| no vanes | - | {mb:.3e} | {eb:.1e} |",
             f"| Freniere construction, square edges ({len(square.vanes)} vanes) | 0 deg | {ms:.3e} | {es:.1e} |",
             f"| Freniere construction | {spec.bevel_deg:g} deg {spec.bevel_side} | {mf:.3e} | {ef:.1e} |",
             f"| optimised | {s.bevel_deg:g} deg {s.bevel_side} | {mo:.3e} | {eo:.1e} |", "",
             f"**Freniere / optimised = {ratio:.3f} +- {ratio_se:.3f}** (target >= 1.3).", "",
             "Candidates tried (CRN objective J = mean ln PST, lower is better; start "
             f"{res.start_objective:.3f} +- {res.start_objective_stderr:.3f}):", "",
             "| stage | bevel | J |", "|---|---|---|"]
    for t in res.tried:
        j = "n/a" if t["objective"] is None else f"{t['objective']:.3f}"
        lines.append(f"| {t['stage']} | {t['bevel_deg']:g} deg {t['bevel_side']} | {j} |")
    lines += ["", "Per angle (independent re-trace): " + "; ".join(
        f"{f.off_axis_deg:g} deg Freniere {f.pst:.2e} +- {f.pst_stderr:.1e}, optimised {o.pst:.2e} +- {o.pst_stderr:.1e}"
        for f, o in zip(fre, opt))]
    lines += ["", f"Why not more: the Freniere construction is complete here (lit-and-seen wall "
              f"{built.lit_and_seen_mm:.3g} mm: no wall section lit at E or beyond is seen by the detector), so "
              "single-scatter wall paths are already gone and what is left is scatter from the vanes' inner edges "
              "and faces and multiple bounces between vanes. Knife-edging (bevel) removes the square edges' lit and "
              f"seen edge face (x{ms / mf:.0f} over square edges at this count); moving vanes along z or changing "
              "the bevel angle or side then only shifts that edge-and-face residual by ~10 % (the table above). "
              "Hole radii are kept on the field envelope: a larger hole uncovers wall, a smaller one vignettes F."]
    from results_md import publish

    publish("vane_optimiser", "\n".join(lines), write=not args.no_write)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
