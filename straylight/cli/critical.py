"""``straylight critical``: critical (seen by the detector) and illuminated (lit by the beam) parts.

    straylight critical SCENE.toml --angle-deg A [--rays N] [--seed S] --out DIR
    straylight critical --builtin tube --angle-deg 20 --out DIR

Writes DIR/critical.json (CONTRACTS §4.5: ``parts`` with ``illuminated``, ``view_factor``,
``score`` and their standard errors), critical.csv, critical.md and critical.png.
"""
from __future__ import annotations

from pathlib import Path


def add_parser(subparsers):
    from straylight.cli.pst import add_common_scene_args, add_dask_out_args, add_one_angle_args

    p = subparsers.add_parser("critical", help="critical and illuminated parts at one off-axis angle",
                              description=__doc__.splitlines()[0])
    add_common_scene_args(p)
    add_one_angle_args(p, 100_000, "rays each way (beam forward, detector reverse)")
    add_dask_out_args(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from straylight.cli.cluster_args import execution
    from straylight.cli.pst import check_angle_deg, load_instrument

    check_angle_deg(args.angle_deg)
    if args.rays < 2:
        raise ValueError(f"--rays must be >= 2, got {args.rays}")
    inst = load_instrument(args)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with execution(args, in_process_below=2) as ex:
        report = inst.critical(args.angle_deg, args.azimuth_deg, rays=args.rays, seed=args.seed, execution=ex)
    report.write_json(out / "critical.json")
    report.write_csv(out / "critical.csv")
    import atomicio

    atomicio.write_text(out / "critical.md", report.markdown())
    report.plot(out / "critical.png")
    print(report.markdown())
    print(f"written {out}/critical.json, critical.csv, critical.md, critical.png")
    return 0
