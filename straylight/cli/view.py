"""``straylight view``: the scene in 3-D with traced rays; a PNG off screen or an interactive window.

    straylight view --builtin tube [--angle-deg 20] [--rays 200] [--color-by part|absorbed] [--png out.png]
    straylight view SCENE.toml --png scene.png
    straylight view SCENE.toml --html view.html [--angle-deg 20] [--trace-rays 50000]   # interactive, in a browser
    straylight view ASSEMBLY.step [--png parts.png]    # a STEP/IGES/STL file as it is: its parts, no rays

Without a display (and without --png) the picture goes to scene.png, and the command says so.
"""
from __future__ import annotations

import math


MAX_DRAWN_RAYS = 100_000  # ray paths drawn by --rays (each a polyline held in memory)


def add_parser(subparsers):
    from straylight.cli.pst import add_common_scene_args

    p = subparsers.add_parser("view", help="3-D view of a scene with traced rays", description=__doc__.splitlines()[0])
    add_common_scene_args(p)
    p.add_argument("--png", default=None, help="write this PNG (off screen) instead of opening a window")
    p.add_argument("--html", default=None, metavar="FILE",
                   help="write the interactive 3-D view (one HTML file, opens in a browser without a server): parts "
                        "coloured by absorbed power, the ranked paths' sample rays (--trace-rays rays traced)")
    p.add_argument("--angle-deg", type=float, default=20.0, help="off-axis angle of the drawn beam")
    p.add_argument("--rays", type=int, default=200, help="ray paths to draw (0: none)")
    p.add_argument("--color-by", choices=("part", "absorbed"), default="part")
    p.add_argument("--trace-rays", type=int, default=50_000, help="rays traced for --color-by absorbed and --html")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=run)


def _written(out, args) -> None:
    if out is None:
        return
    if args.png is None:  # no display: the window could not open
        print(f"no display: wrote the picture to {out} (choose the file with --png FILE; --html FILE for the "
              f"interactive view in a browser)")
    else:
        print(f"written {out}")


def run(args) -> int:
    from pathlib import Path

    from straylight import viz
    from straylight.cli.pst import check_angle_deg, load_instrument

    check_angle_deg(args.angle_deg)
    if args.rays > MAX_DRAWN_RAYS:  # 1e9 asked numpy for 29.8 GiB of polylines
        raise ValueError(f"--rays {args.rays} is above {MAX_DRAWN_RAYS} drawn ray paths (a picture shows no more; "
                         f"--trace-rays sets the rays traced for the colours and --html)")
    if args.scene is not None and args.builtin is None:
        from geometry.io import CAD_SUFFIXES, MESH_SUFFIXES, load_scene_or_file

        if Path(args.scene).suffix.lower() in CAD_SUFFIXES + MESH_SUFFIXES:  # a one-file scene: parts, no beam
            if args.html is not None:
                raise ValueError(f"{args.scene}: --html traces the scene's beam; a CAD file has none: write a scene "
                                 f"with `straylight geometry scene {args.scene} -o scene.toml`")
            scene = load_scene_or_file(args.scene)
            _written(viz.render_scene(scene, args.png, title=f"{Path(args.scene).name}: {len(scene.parts)} parts"),
                     args)
            return 0
    inst = load_instrument(args)
    setup = inst.setup
    if args.html is not None:
        out = inst.view3d(args.html, args.angle_deg, rays=args.trace_rays, seed=args.seed)
        print(f"written {out}")
        if args.png is None:
            return 0
    a = math.radians(args.angle_deg)
    paths = viz.trace_ray_paths(setup, a, n_rays=args.rays, seed=args.seed) if args.rays > 0 else None
    absorbed = None
    if args.color_by == "absorbed":
        from straylight.cli.cluster_args import execution
        from straylight.trace import trace

        with execution(args) as ex:  # this process, progress on stderr
            res = trace(setup.scene, [setup.beam.source(a)], n_rays=args.trace_rays, seed=args.seed,
                        materials=setup.materials, execution=ex)
        absorbed = {k: v.power_w for k, v in res.absorbed.items()}
    out = viz.render_scene(setup.scene, args.png, color_by=args.color_by, absorbed_w=absorbed, ray_paths=paths,
                           title=f"{setup.description}; beam {args.angle_deg:g} deg off axis")
    _written(out, args)
    return 0
