"""The ghost table of the 10-surface double Gauss (ray-optics' ag_dblgauss.seq), timed (BENCHMARK: <= 60 s).

    .venv/bin/python benchmarks/ghosts.py [--lens tests/data/lenses/ray-optics/ag_dblgauss.seq] [--walk-rays 1000000]

Imports the lens (``optics import``), runs the ghost table (``straylight.analyses.ghost_trace``: every
two-reflection ghost to 2 %, ghosts below 1e-6 of the nominal image stopped early) and, as the baseline
measured in the same run, the tracer's analog random walk with path records: its time for
``--walk-rays`` rays and the worst relative error among the same ghosts, extrapolated to the time the
walk would need for 2 % on every ghost (time x (worst error / 0.02)^2; a ghost the walk never drew counts the
error of its expected hits, rays x the table's ghost power / the source power). Prints both and their ratio.
"""
from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lens", default=str(ROOT / "tests" / "data" / "lenses" / "ray-optics" / "ag_dblgauss.seq"))
    ap.add_argument("--walk-rays", type=int, default=1_000_000)
    ap.add_argument("--no-write", action="store_true", help="print only; leave benchmarks/RESULTS.md alone")
    args = ap.parse_args(argv)
    from straylight.analyses.ghost_trace import ghosts
    from straylight.analyses.ghosts import specular_sequence
    from straylight.execution import Execution
    from straylight.cli.main import main as cli
    from straylight.scene import load_scene
    from straylight.trace import EstimatorOptions, OutputOptions, TraceOptions

    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        assert cli(["optics", "import", args.lens, "--out", tmp]) == 0
        t_import = time.perf_counter() - t0
        rs = load_scene(Path(tmp) / "scene.toml")
        t0 = time.perf_counter()
        table = ghosts(rs, order=2, execution=Execution(workers=1))  # one process, as the walk below: the ratio is per core
        t_table = time.perf_counter() - t0
        wanted = [r for r in table.rows if r.fraction_of_nominal >= 1e-6]
        worst = max(r.stderr_w / r.power_w for r in wanted)
        t0 = time.perf_counter()
        res = rs.trace(args.walk_rays, seed=1, options=TraceOptions(
            estimator=EstimatorOptions(nee=False), output=OutputOptions(record_paths=True, path_depth=40)))
        t_walk = time.perf_counter() - t0
    groups = {g.key: g for g in res.paths.group(by=lambda ev, det: specular_sequence(ev) if det == "image" else None)
              if g.key is not None}
    walk_err = []
    never = 0
    for r in wanted:
        g = groups.get(tuple(r.sequence))
        if g is not None and g.power_w > 0:
            walk_err.append(g.stderr_w / g.power_w)
        else:  # never drawn: the relative error of a Poisson count of its expected analog hits, N P_g / P_source
            never += 1
            walk_err.append(1.0 / math.sqrt(max(args.walk_rays * r.power_w / res.emitted_w, 1e-300)))
    worst_walk = max(walk_err)
    t_walk_2pc = t_walk * (worst_walk / 0.02) ** 2
    print(f"lens {Path(args.lens).name}: import {t_import:.2f} s; {len(table.rows)} ghosts, {len(wanted)} >= 1e-6 of "
          f"the nominal image")
    print(f"ghost table: {t_table:.1f} s, worst relative error {worst:.4f} (target 0.02)")
    print(f"analog walk: {args.walk_rays:.0e} rays in {t_walk:.1f} s, worst relative error {worst_walk:.3f} "
          f"({never} ghosts never drawn: their error is that of their expected hits, N x ghost power / source power) "
          f"-> ~{t_walk_2pc:.3g} s for 2 % on every ghost")
    print(f"ratio: ghost table {t_walk_2pc / t_table:.3g}x faster than the analog walk to the same precision")
    if not args.no_write:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from results_md import write_section

        write_section("ghosts", "\n".join([
            f"Lens `{Path(args.lens).name}`: import {t_import:.2f} s; {len(table.rows)} two-reflection ghosts, "
            f"{len(wanted)} >= 1e-6 of the nominal image.", "",
            "| estimator | seconds | worst relative error over those ghosts |", "|---|---|---|",
            f"| ghost table (forced sequences) | {t_table:.1f} | {worst:.4f} |",
            f"| analog walk, {args.walk_rays:.0e} rays | {t_walk:.1f} | {worst_walk:.3f} |",
            f"| analog walk to 2 % (extrapolated) | {t_walk_2pc:.3g} | 0.02 |", "",
            f"{never} of those ghosts never drawn by the walk: their error is that of a Poisson count of their expected "
            "hits (rays x the table's ghost power / the source power).", "",
            f"Ghost table {t_walk_2pc / t_table:.3g}x faster than the analog walk to the same precision "
            "(BENCHMARK target: <= 60 s)."]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
