"""``straylight view``: the scene in 3-D with traced rays; a PNG off screen or an interactive window.

    straylight view --builtin tube [--angle-deg 20] [--rays 200] [--color-by part|absorbed] [--png out.png]
    straylight view SCENE.toml --png scene.png
    straylight view SCENE.toml --html view.html [--angle-deg 20] [--trace-rays 50000]   # interactive, in a browser
"""
from __future__ import annotations

import math


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


def run(args) -> int:
    from straylight import viz
    from straylight.cli.pst import check_angle_deg, load_instrument

    check_angle_deg(args.angle_deg)
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
    if out is not None:
        print(f"written {out}")
    return 0
