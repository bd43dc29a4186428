"""``straylight ghosts``: the ghost table of the lenses in a scene (CONTRACTS 8.4; docs/ghosts.md).

    straylight ghosts SCENE.toml [--order 2] [--field-deg F] [--max-total-rays N] [--max-seconds S]
        [--workers K] --out DIR

Writes DIR/ghosts.csv, ghosts.json, ghosts.md and ghosts.png (straylight.analyses.ghost_trace).
"""
from __future__ import annotations


def add_parser(subparsers):
    p = subparsers.add_parser("ghosts", help="ghost table of the lenses in a scene (every even-reflection path)",
                              description=__doc__.splitlines()[0])
    p.add_argument("scene", help="scene.toml (for example from `straylight optics import`)")
    p.add_argument("--order", type=int, default=2, help="most reflections per ghost, even (default 2)")
    p.add_argument("--field-deg", type=float, default=0.0,
                   help="field angle: the source turned about x, +z toward (0, sin F, cos F) (default 0)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--detector", default=None, help="detector part (default: the scene's first detector)")
    p.add_argument("--target-rel-error", type=float, default=0.02,
                   help="relative standard error each ghost is traced to (default 0.02)")
    p.add_argument("--min-fraction", type=float, default=1e-6,
                   help="ghosts below this fraction of the nominal image's power stop early (default 1e-6)")
    p.add_argument("--max-rays", type=int, default=400_000, help="ray budget per ghost (default 400000)")
    p.add_argument("--max-total-rays", type=int, default=None,
                   help="rays all the ghosts share, the nominal image's aside (default 4000000; a ghost the budget "
                        "stops keeps the error it reached, and the table says how many)")
    p.add_argument("--max-seconds", type=float, default=None,
                   help="wall-clock cap on the whole command, writing its files included (default: none); every "
                        "ghost gets its first rays before any gets more, a ghost the cap stops keeps the error it "
                        "reached, and the table says how many and at what error")
    p.add_argument("--workers", type=int, default=None,
                   help="processes the ghosts are traced on (default: one a core this process may use; 1: this "
                        "process alone); without --max-seconds the table is the same for any number")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-view3d", action="store_true",
                   help="skip DIR/view3d.html (the lens with the nominal path and the strongest ghosts, each selectable)")
    p.set_defaults(func=run, processes=True)  # --workers forks processes (the command line's memory check)


def run(args) -> int:
    import sys

    from straylight.analyses.ghost_trace import WRITE_RESERVE_S, GhostError, ghosts, markdown, write_table
    from straylight.cli.cluster_args import forked_execution
    from straylight.progress import progress_bar

    if args.order < 2 or args.order % 2:
        raise GhostError(f"--order must be an even number >= 2, got {args.order}")
    if not -90 < args.field_deg < 90:
        raise GhostError(f"--field-deg must be in (-90, 90), got {args.field_deg:g}")
    if not 0 < args.target_rel_error < 1:
        raise GhostError(f"--target-rel-error must be in (0, 1), got {args.target_rel_error:g}")
    if not 0 <= args.min_fraction < 1:
        raise GhostError(f"--min-fraction must be in [0, 1), got {args.min_fraction:g}")
    for flag, value in (("--max-rays", args.max_rays), ("--max-total-rays", args.max_total_rays)):
        if value is not None and value < 1:
            raise GhostError(f"{flag} must be >= 1, got {value}")
    if args.max_seconds is not None and not args.max_seconds > 0:  # (NaN too)
        raise GhostError(f"--max-seconds must be > 0, got {args.max_seconds:g}")
    if args.workers is not None and args.workers < 1:
        raise GhostError(f"--workers must be >= 1, got {args.workers}")
    bar = progress_bar(total=None, desc="ghosts", unit="ghost", enabled=sys.stderr.isatty())

    def tick(k, n):
        bar.total = n
        bar.update(1)

    try:
        table = ghosts(args.scene, order=args.order, field_deg=args.field_deg, detector=args.detector,
                       target_rel_error=args.target_rel_error, min_fraction=args.min_fraction,
                       max_rays=args.max_rays, seed=args.seed, on_ghost=tick, max_seconds=args.max_seconds,
                       execution=forked_execution(args),
                       # the cap bounds the command (ghosts() counts from its call, the scene's loading included):
                       # the ghosts leave time to write the table, maps and 3-D view
                       reserve_s=0.0 if args.max_seconds is None else min(WRITE_RESERVE_S, 0.3 * args.max_seconds),
                       **({} if args.max_total_rays is None else {"max_total_rays": args.max_total_rays}))
    finally:
        bar.close()
    for warning in table.warnings:  # the rest of the notes (how the table was traced) are in ghosts.md
        print(f"straylight: warning: {warning}", file=sys.stderr)
    write_table(table, args.out)
    written = "ghosts.csv, ghosts.json, ghosts.md, ghosts.png"
    if not args.no_view3d and table.optics is not None:
        from pathlib import Path

        from straylight.analyses.ghost_trace import write_view3d
        from straylight.analyses.scene_setup import scene_setup

        write_view3d(table, table.optics, scene_setup(args.scene, detector=args.detector), Path(args.out) / "view3d.html",
                     seed=args.seed)
        written += ", view3d.html"
    print(markdown(table, top=15, warnings=False))  # (printed above)
    print(f"written {args.out}/{written}")
    return 0
