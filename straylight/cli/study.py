"""``straylight study``: every analysis of an instrument, written as a report folder.

    straylight study --out report [--rays N] [--seed S] [--workers K]      # the built-in tube
    straylight study SCENE.toml --out report [--rays N] [--seed S]           # your own instrument
    straylight study --model mydesign.py:build --sweep-parameter vane_count --sweep-values 3 5 7 --out report
    straylight study --builtin cassegrain --out report [--rays N]          # the built-in telescope

Open DIR/index.html (numbers in DIR/results.json). See docs/study.md for what each step computes.
"""
from __future__ import annotations


def add_parser(subparsers):
    p = subparsers.add_parser("study", help="stray-light study: PST, paths, critical objects, design sweep",
                              description=__doc__.splitlines()[0])
    p.add_argument("scene", nargs="?", metavar="SCENE.toml",
                   help="scene file (CONTRACTS §6); default: the built-in tube")
    p.add_argument("--builtin", choices=("tube", "cassegrain"), default=None,
                   help="the built-in baffled tube (the default) or the built-in Cassegrain telescope")
    p.add_argument("--model", default=None, metavar="FILE.py:FUNCTION",
                   help="your parametric CadQuery design: FUNCTION(**params) returns named parts; the study runs "
                        "on its defaults and --sweep-parameter/--sweep-values sweep its parameters (docs/study.md)")
    p.add_argument("--out", required=True, help="report directory (created)")
    from straylight.cli.pst import add_precision_args

    add_precision_args(p, default_rays=None,
                       what=f"rays per PST angle (default: each PST point traced to {DEFAULT_TARGET_REL_ERROR * 100:g} %% "
                            f"with a reliable error, at most {DEFAULT_POINT_RAYS:.0e} rays per point, so the same seed gives the "
                            f"same numbers on any machine); the other "
                            f"steps scale from it (default {DEFAULT_RAYS})", exclusive=False)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=None, help="dask LocalCluster with K worker threads (K processes "
                                                               "with --processes; default: in-process)")
    p.add_argument("--scheduler", default=None, help="dask scheduler address")
    p.add_argument("--detector", default=None, help="scene file: detector part (default: [analysis] or the only one)")
    p.add_argument("--material", default=None, help="built-in tube: coating of wall, vanes and end plate "
                                                     "(default z302_sample_b)")
    p.add_argument("--angles-deg", type=float, nargs="+", default=None, help="PST angles")
    p.add_argument("--path-angle-deg", type=float, default=None,
                   help="off-axis angle of the path, critical-object and view steps (default 20)")
    p.add_argument("--sweep-parameter", default="vane_count",
                   help="built-in tube: parameter of the design sweep (a geometry.parts.tube.TubeParams field, "
                        "e.g. vane_count, vane_inner_radius_mm, vane_bevel_deg)")
    p.add_argument("--sweep-values", type=float, nargs="+", default=None,
                   help="values of the swept parameter (default for vane_count: 0 .. 9)")
    p.add_argument("--no-sweep", action="store_true", help="skip the design sweep")
    p.add_argument("--band-um", type=float, nargs=2, default=None, metavar=("LO", "HI"),
                   help="band of the self-emission budget when parts have temperature_k (default 8 12)")
    p.add_argument("--resume", action="store_true",
                   help="continue an interrupted study in the same --out: finished PST and design-sweep points "
                        "are read back (same numbers); refused if the settings changed")
    from straylight.cli.cluster_args import add_cluster_args

    add_cluster_args(p)
    p.set_defaults(func=run)


DEFAULT_RAYS = 200_000
DEFAULT_TARGET_REL_ERROR = 0.02
DEFAULT_POINT_RAYS = 2_000_000  # a ray budget, not wall seconds: the same seed, the same numbers under any load


def default_precision(args) -> None:
    """Neither --rays nor --target-rel-error: the PST points trace to DEFAULT_TARGET_REL_ERROR with a
    reliable error (VOV <= 0.1) within a budget of DEFAULT_POINT_RAYS rays each (--max-rays changes
    it; --max-seconds adds a wall cap, which then says it stopped the run), not a fixed ray count; the
    other steps use DEFAULT_RAYS. A ray budget keeps a seed's numbers the same on a loaded or an idle
    machine. A point the budget stops is flagged in the report, the plot and pst.json."""
    if args.rays is None and args.target_rel_error is None:
        args.target_rel_error = DEFAULT_TARGET_REL_ERROR
        if args.max_rays is None and args.max_seconds is None:
            args.max_rays = DEFAULT_POINT_RAYS
    if args.rays is None:
        args.rays = DEFAULT_RAYS


def run(args) -> int:
    from straylight.analyses.report import StudyConfig, run_study
    from straylight.cli.pst import precision_from_args

    if sum(x is not None for x in (args.scene, args.builtin, args.model)) > 1:
        raise ValueError("give one of SCENE.toml, --builtin tube or --model FILE.py:FUNCTION")
    if args.builtin == "cassegrain":
        if args.resume:
            raise ValueError("--resume is not available for --builtin cassegrain")
        return _cassegrain(args)
    default_precision(args)
    precision = precision_from_args(args)
    if args.rays < 100:
        raise ValueError(f"--rays must be at least 100, got {args.rays}")
    if (args.scene is not None or args.model is not None) and args.material is not None:
        raise ValueError("--material applies to the built-in tube; a scene file names its own materials")
    if args.scene is None and args.model is None and args.detector is not None:
        raise ValueError("--detector applies to a scene file or a model")
    cfg = StudyConfig(rays=args.rays, seed=args.seed,
                      material=args.material or "z302_sample_b", scene=args.scene, detector=args.detector,
                      sweep=not args.no_sweep, precision=precision, model=args.model)
    if args.angles_deg:
        cfg.angles_deg = tuple(args.angles_deg)
    if args.band_um:
        from straylight.thermal.planck import check_band

        cfg.thermal_band_um = check_band(*args.band_um)
    if args.path_angle_deg is not None:
        from straylight.cli.pst import check_angle_deg

        check_angle_deg(args.path_angle_deg, "--path-angle-deg")
        cfg.path_angle_deg = args.path_angle_deg
    cfg.sweep_parameter = args.sweep_parameter
    if args.sweep_values:
        if args.scene is not None:
            raise ValueError("--sweep-values sweeps a built-in tube parameter; a scene file has none "
                             "(use --model FILE.py:build for your own parametric design)")
        cfg.sweep_values = tuple(args.sweep_values)
    elif args.sweep_parameter != "vane_count" and args.scene is None and args.model is None:
        raise ValueError(f"--sweep-values is needed to sweep {args.sweep_parameter}")
    if args.model is not None:
        from straylight.analyses.model import check_parameter, load_model

        fn, _ = load_model(args.model)  # a bad file or parameter fails now, not after the first steps
        if args.sweep_values:
            check_parameter(fn, args.sweep_parameter, args.model.rsplit(":", 1)[0])
        else:
            cfg.sweep_values = ()  # a model is swept only over the values given
    from straylight.cli.cluster_args import execution

    with execution(args, in_process_below=2) as ex:  # one cluster for every step; one worker: this process
        result = run_study(args.out, cfg, resume=args.resume, execution=ex)
    print(f"study written to {result.out_dir}/index.html ({result.timings_s['total']:.0f} s)")
    return 0


def _cassegrain(args) -> int:
    """The telescope study (straylight.analyses.telescope): PST with its contributions, ghosts."""
    from straylight.analyses.telescope import TelescopeStudy, run_telescope_study
    from straylight.cli.cluster_args import execution

    if args.rays is None:
        args.rays = DEFAULT_RAYS
    if args.rays < 100:
        raise ValueError(f"--rays must be at least 100, got {args.rays}")
    cfg = TelescopeStudy(rays=args.rays, seed=args.seed)
    if args.angles_deg:
        cfg.angles_deg = tuple(args.angles_deg)
    with execution(args, in_process_below=2) as ex:
        run_telescope_study(args.out, cfg, execution=ex)
    print(f"study written to {args.out}/index.html ({cfg.timings_s['total']:.0f} s)")
    return 0
