"""``straylight study``: the baffle design study on the built-in tube, written as a report folder.

    straylight study --out report [--rays N] [--seed S] [--workers K]

Open DIR/index.html. See docs/study.md for what each step computes.
"""
from __future__ import annotations


def add_parser(subparsers):
    p = subparsers.add_parser("study", help="baffle design study: PST, paths, critical objects, design sweep",
                              description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True, help="report directory (created)")
    p.add_argument("--rays", type=int, default=200_000, help="rays per PST angle; other steps scale from it")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=None, help="dask LocalCluster with K worker threads (default: in-process)")
    p.add_argument("--scheduler", default=None, help="dask scheduler address")
    p.add_argument("--material", default="z302_sample_b", help="coating of wall, vanes and end plate")
    p.add_argument("--angles-deg", type=float, nargs="+", default=None, help="PST angles")
    p.add_argument("--sweep-parameter", default="vane_count",
                   help="tube parameter of the design sweep (a geometry.parts.tube.TubeParams field, "
                        "e.g. vane_count, vane_inner_radius_mm, vane_bevel_deg)")
    p.add_argument("--sweep-values", type=float, nargs="+", default=None,
                   help="values of the swept parameter (default for vane_count: 0 .. 9)")
    p.set_defaults(func=run)


def run(args) -> int:
    from straylight.analyses.report import StudyConfig, run_study

    if args.rays < 100:
        raise ValueError(f"--rays must be at least 100, got {args.rays}")
    cfg = StudyConfig(rays=args.rays, seed=args.seed, workers=args.workers, scheduler=args.scheduler,
                      material=args.material)
    if args.angles_deg:
        cfg.angles_deg = tuple(args.angles_deg)
    cfg.sweep_parameter = args.sweep_parameter
    if args.sweep_values:
        cfg.sweep_values = tuple(args.sweep_values)
    elif args.sweep_parameter != "vane_count":
        raise ValueError(f"--sweep-values is needed to sweep {args.sweep_parameter}")
    result = run_study(args.out, cfg)
    print(f"study written to {result.out_dir}/index.html ({result.timings_s['total']:.0f} s)")
    return 0
