"""``straylight paths``: stray-light paths to the detector, ranked by power fraction.

    straylight paths --builtin tube --angle-deg 20 --rays N --seed S --out DIR
        [--group-by sequence|family|first_part|last_part|ancestry] [--ancestry scattered_once ...] [--top 20] [--ghosts]
        [--view3d]

Writes DIR/paths.md (table), paths.csv (every group), paths.json, paths.png (bar plot); with --view3d
also DIR/view3d.html (the interactive 3-D view, docs/notebook.md). Each group has its share of the
power and its share of the estimate's variance (which paths make the error bar).
"""
from __future__ import annotations

from pathlib import Path


def add_parser(subparsers):
    from straylight.paths import ANCESTRY, GROUP_BY  # not analyses.paths_report: the parser stays light
    from straylight.cli.pst import add_common_scene_args, add_dask_out_args, add_one_angle_args

    p = subparsers.add_parser("paths", help="stray-light path report at one off-axis angle",
                              description=__doc__.splitlines()[0])
    add_common_scene_args(p)
    add_one_angle_args(p, 200_000)
    p.add_argument("--no-nee", action="store_true", help="plain random walk (no next-event estimation)")
    p.add_argument("--group-by", choices=GROUP_BY, default="sequence")
    p.add_argument("--ancestry", choices=ANCESTRY, nargs="+", default=None, help="keep only these classes")
    p.add_argument("--top", type=int, default=20, help="rows in the table and bars in the plot")
    p.add_argument("--view3d", action="store_true",
                   help="also write DIR/view3d.html: the interactive 3-D view of this trace (parts by absorbed "
                        "power, each ranked path's sample rays; opens in a browser without a server)")
    p.add_argument("--ghosts", action="store_true",
                   help="also rank the specular paths (nominal and ghosts): DIR/ghosts.md, ghosts.json")
    add_dask_out_args(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from straylight.cli.pst import check_angle_deg, load_instrument

    check_angle_deg(args.angle_deg)
    if args.top < 1:
        raise ValueError(f"--top must be >= 1 (rows in the table), got {args.top}")
    inst = load_instrument(args)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    from straylight.cli.cluster_args import execution

    with execution(args, in_process_below=2) as ex:
        report = inst.paths(args.angle_deg, args.azimuth_deg, rays=args.rays, seed=args.seed, nee=not args.no_nee,
                            group_by=args.group_by, ancestry=args.ancestry, execution=ex)
    res = report.trace
    import atomicio

    atomicio.write_text(out / "paths.md", report.markdown(args.top))
    report.write_csv(out / "paths.csv")
    report.write_json(out / "paths.json")
    report.plot(out / "paths.png", top=args.top)
    print(report.markdown(min(args.top, 10)))
    if args.ghosts:
        from straylight.analyses.ghosts import ghost_table

        table = ghost_table(res.paths, report.detector, report.total_w)
        table.write(out)
        print(table.markdown(min(args.top, 10)))
    if args.view3d:
        inst.view3d(out / "view3d.html", args.angle_deg, args.azimuth_deg, seed=args.seed, paths=report)
    print(f"written {out}/paths.md, paths.csv, paths.json, paths.png" + (", ghosts.md, ghosts.json" if args.ghosts else "")
          + (", view3d.html" if args.view3d else ""))
    return 0
