"""``straylight critical``: critical (seen by the detector) and illuminated (lit by the beam) parts.

    straylight critical SCENE.toml --angle-deg A [--rays N] [--seed S] --out DIR
    straylight critical --builtin tube --angle-deg 20 --out DIR

Writes DIR/critical.json (CONTRACTS §4.5: ``parts`` with ``illuminated``, ``view_factor``,
``score`` and their standard errors), critical.csv, critical.md and critical.png.
"""
from __future__ import annotations

import math
from pathlib import Path


def add_parser(subparsers):
    from straylight.cli.pst import add_common_scene_args

    p = subparsers.add_parser("critical", help="critical and illuminated parts at one off-axis angle",
                              description=__doc__.splitlines()[0])
    add_common_scene_args(p)
    p.add_argument("--angle-deg", type=float, required=True, help="off-axis angle of the beam")
    p.add_argument("--azimuth-deg", type=float, default=0.0)
    p.add_argument("--rays", type=int, default=100_000, help="rays each way (beam forward, detector reverse)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=None)
    p.add_argument("--scheduler", default=None)
    p.add_argument("--out", required=True, help="output directory")
    p.set_defaults(func=run)


def run(args) -> int:
    from straylight.analyses.critical import critical_objects
    from straylight.analyses.pst import dask_client
    from straylight.cli.pst import load_setup

    if not -90 < args.angle_deg < 90:
        raise ValueError(f"--angle-deg must be in (-90, 90), got {args.angle_deg}")
    if args.rays < 2:
        raise ValueError(f"--rays must be >= 2, got {args.rays}")
    setup = load_setup(args)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with dask_client(args.workers, args.scheduler) as client:
        report = critical_objects(setup, math.radians(args.angle_deg), math.radians(args.azimuth_deg),
                                  n_rays=args.rays, seed=args.seed, client=client, progress=True)
    report.write_json(out / "critical.json")
    report.write_csv(out / "critical.csv")
    import atomicio

    atomicio.write_text(out / "critical.md", report.markdown())
    report.plot(out / "critical.png")
    print(report.markdown())
    print(f"written {out}/critical.json, critical.csv, critical.md, critical.png")
    return 0
