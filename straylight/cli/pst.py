"""``straylight pst``: point source transmittance vs off-axis angle.

    straylight pst --builtin tube [--vanes N] --angles-deg 0 5 10 20 30 --rays N --seed S --out DIR
    straylight pst SCENE.toml [--entrance-center-mm X Y Z --entrance-radius-mm R] --angles-deg ... --out DIR

With a scene file, the beam is the file's ``collimated_disk`` source, tilted away from its own
direction; the file's optional [analysis] table names the detector and the entrance
(docs/study.md, "Your own instrument").
Writes DIR/pst.csv, pst.json, and with two off-axis angles or more (or ``--plot``) the curve pst.png (and
entrance_ratio.png with an entrance): one angle is one point, which the printed line and the files carry.
"""
from __future__ import annotations

import math
from pathlib import Path

from straylight.cli.long_lived import long_lived_objects


def add_common_scene_args(parser):
    """SCENE.toml or --builtin tube (+ tube overrides), used by pst, paths and view."""
    parser.add_argument("scene", nargs="?", help="scene TOML file (CONTRACTS §6)")
    parser.add_argument("--builtin", choices=("tube", "cassegrain"),
                        help="use the built-in baffled tube (or the built-in Cassegrain telescope) instead of a file")
    parser.add_argument("--vanes", type=int, default=None, help="built-in tube: number of vanes")
    parser.add_argument("--vane-inner-radius-mm", type=float, default=None, help="built-in tube: vane hole radius")
    parser.add_argument("--material", default=None, help="built-in tube: coating (preset or file; default z302_sample_b)")
    parser.add_argument("--detector", default=None, help="detector part name (default: the only detector)")


def add_one_angle_args(parser, default_rays: int, rays_help: str | None = None):
    """--angle-deg, --azimuth-deg, --rays, --seed: one beam direction, used by paths and critical."""
    parser.add_argument("--angle-deg", type=float, required=True, help="off-axis angle of the beam")
    parser.add_argument("--azimuth-deg", type=float, default=0.0)
    parser.add_argument("--rays", type=int, default=default_rays, help=rays_help)
    parser.add_argument("--seed", type=int, default=0)


def add_dask_out_args(parser):
    """--workers, --scheduler, --out (required output directory)."""
    parser.add_argument("--workers", type=int, default=None)
    parser.add_argument("--scheduler", default=None)
    from straylight.cli.cluster_args import add_insecure_arg

    add_insecure_arg(parser)
    parser.add_argument("--out", required=True, help="output directory")


def check_angle_deg(value: float, flag: str = "--angle-deg") -> None:
    """An off-axis angle must lie in (-90, 90) deg."""
    if not -90 < value < 90:
        raise ValueError(f"{flag} must be in (-90, 90), got {value}")


def add_precision_args(parser, default_rays=None, what="rays", exclusive=True):
    """``--rays N`` or ``--target-rel-error E`` (with its caps), shared by pst, study and trace
    (study: not exclusive, its other steps still use --rays)."""
    group = parser.add_mutually_exclusive_group(required=default_rays is None) if exclusive else parser
    group.add_argument("--rays", type=int, default=default_rays,
                       help=what + (f" (default {default_rays})" if default_rays else ""))
    group.add_argument("--target-rel-error", type=float, default=None, metavar="E",
                       help="trace in growing rounds until the relative standard error is <= E (e.g. 0.02) "
                            "with a reliable error estimate (VOV <= --max-vov), or a cap (docs/study.md)")
    parser.add_argument("--max-rays", type=float, default=None,
                        help="with --target-rel-error: stop at this many rays (default 5e7)")
    parser.add_argument("--max-seconds", type=float, default=None,
                        help="with --target-rel-error: stop after this wall time (s; per point for pst)")
    parser.add_argument("--max-vov", type=float, default=None,
                        help="with --target-rel-error: largest variance of the variance accepted (default 0.1)")


def precision_from_args(args):
    """A :class:`straylight.analyses.precision.Precision`, or None for a fixed ray count
    (:func:`straylight.api.precision_target`; errors name the flags)."""
    from straylight.api import precision_target

    caps = {"--max-rays": args.max_rays, "--max-seconds": args.max_seconds, "--max-vov": args.max_vov}
    if args.target_rel_error is None:
        given = [k for k, v in caps.items() if v is not None]
        if given:
            raise ValueError(f"{', '.join(given)} need --target-rel-error")
        return None
    if not 0 < args.target_rel_error < 1:
        raise ValueError(f"--target-rel-error must be in (0, 1), e.g. 0.02, got {args.target_rel_error}")
    return precision_target(args.target_rel_error, args.max_rays, args.max_seconds, args.max_vov)


def add_parser(subparsers):
    p = subparsers.add_parser("pst", help="point source transmittance vs off-axis angle",
                              description=__doc__.splitlines()[0])
    add_common_scene_args(p)
    p.add_argument("--angles-deg", type=float, nargs="+", default=[0, 5, 10, 15, 20, 30, 45])
    p.add_argument("--azimuths-deg", type=float, nargs="+", default=[0.0])
    add_precision_args(p, default_rays=200_000, what="rays per angle")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-nee", action="store_true", help="plain random walk (no next-event estimation)")
    from straylight.cli.diffraction_args import add_diffraction_arg

    add_diffraction_arg(p)
    p.add_argument("--wavelength-nm", type=float, default=None,
                   help="the beam's wavelength (overrides the source's wavelength_nm; used by edge diffraction)")
    from straylight.analyses.estimators import ESTIMATOR_SETS

    p.add_argument("--estimators", choices=tuple(ESTIMATOR_SETS), default="default",
                   help="estimator set (straylight.analyses.estimators): 'default'; 'lens' also draws the scatter "
                        "points a lens lights behind its glass and joins them to the beam through it (a lens cell "
                        "seen at a glint; 0.7-0.9 CPU s more per 6e4 rays where the beam lights anything behind "
                        "the lens); 'ghosts' also joins the points the beam lights to the sensor through a lens's "
                        "two-reflection ghost (~1 CPU s more per 6e4 rays where the eye chains run); others when "
                        "registered (benchmarks/estimator_sets.py registers the history "
                        "sets the benchmarks time against)")
    p.add_argument("--entrance-center-mm", type=float, nargs=3, default=None)
    p.add_argument("--entrance-radius-mm", type=float, default=None)
    p.add_argument("--workers", type=int, default=None, help="dask LocalCluster with K worker threads "
                                                                   "(K processes with --processes)")
    p.add_argument("--scheduler", default=None, help="dask scheduler address")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--resume", action="store_true",
                   help="continue an interrupted sweep: points already finished (OUT/pst.points/) are not traced again")
    p.add_argument("--plot", action="store_true",
                   help="draw pst.png (and entrance_ratio.png) for a single off-axis angle too (a curve needs two: "
                        "without it, one angle writes no plot)")
    from straylight.cli.cluster_args import add_cluster_args

    add_cluster_args(p)
    p.set_defaults(func=run)


def load_setup(args):
    """A :class:`straylight.analyses.types.Setup` from the common scene arguments (:func:`load_instrument`)."""
    return load_instrument(args).setup


def load_instrument(args):
    """A :class:`straylight.api.Instrument` from the common scene arguments: :func:`straylight.api.load`.

    SCENE.toml goes through :func:`straylight.analyses.scene_setup.scene_setup` (its [analysis]
    table; ``--detector`` and pst's ``--entrance-*`` override it); ``--builtin tube`` builds the tube.
    Without garbage collections (:func:`straylight.cli.long_lived.long_lived_objects`): numba's start and
    the scene live as long as the command.
    """
    with long_lived_objects("scene"):
        return _load_instrument(args)


def _load_instrument(args):
    from straylight import api

    if (args.scene is None) == (args.builtin is None):
        raise ValueError("give either SCENE.toml or --builtin tube")
    tube_flags = ("vanes", "vane_inner_radius_mm", "material")
    if args.builtin == "cassegrain":
        for flag in (*tube_flags, "detector"):
            if getattr(args, flag, None) is not None:
                raise ValueError(f"--{flag.replace('_', '-')} applies to --builtin tube, not to the Cassegrain")
        return api.load(builtin="cassegrain")
    if args.builtin:
        return api.load(builtin="tube", detector=args.detector, material=args.material, vane_count=args.vanes,
                        vane_inner_radius_mm=args.vane_inner_radius_mm)
    for flag in tube_flags:
        if getattr(args, flag, None) is not None:
            raise ValueError(f"--{flag.replace('_', '-')} applies to --builtin tube, not to a scene file")
    radius = getattr(args, "entrance_radius_mm", None)
    center = getattr(args, "entrance_center_mm", None)
    if (radius is None) != (center is None):
        raise ValueError("give --entrance-center-mm and --entrance-radius-mm together")
    return api.load(args.scene, detector=args.detector, entrance_center_mm=center, entrance_radius_mm=radius)


def run(args) -> int:
    from straylight.cli.cluster_args import start_early

    start_early(args, in_process_below=2)  # worker processes: their fork server loads while the scene loads
    precision_from_args(args)  # flag errors first, named as flags
    inst = load_instrument(args)
    setup = inst.setup
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    from straylight.cli.cluster_args import execution

    with execution(args, in_process_below=2) as ex:  # one worker: this process
        res = inst.pst(args.angles_deg, args.azimuths_deg, rays=args.rays, seed=args.seed, nee=not args.no_nee,
                       target_rel_error=args.target_rel_error, max_rays=args.max_rays, max_seconds=args.max_seconds,
                       max_vov=args.max_vov, execution=ex, checkpoint_dir=out / "pst.points",
                       resume=args.resume, diffraction=args.diffraction == "on", wavelength_nm=args.wavelength_nm,
                       estimators=args.estimators)
    res.write_csv(out / "pst.csv")
    res.write_json(out / "pst.json")
    written = ["pst.csv", "pst.json"]
    if args.plot or len(set(float(a) for a in res.off_axis_deg)) >= 2:  # one angle is one point, not a curve
        res.plot(out / "pst.png")
        written.append("pst.png")
        if setup.entrance is not None:
            res.plot(out / "entrance_ratio.png", quantity="entrance_ratio")
            written.append("entrance_ratio.png")
    else:  # a curve left from an earlier sweep into DIR would no longer match pst.json: it goes, as a plot would overwrite it
        for name in ("pst.png", "entrance_ratio.png"):
            (out / name).unlink(missing_ok=True)
    for row in res.flagged_rows():
        rel = row["pst_stderr"] / row["pst"] if row["pst"] > 0 else math.nan
        stop = f", {row['rays']:.3g} rays, stopped by {row['stop_reason']}" if "stop_reason" in row else ""
        vov = row.get("vov")
        print(f"{row['off_axis_deg']:6.2f} deg  az {row['azimuth_deg']:5.1f}  PST {row['pst']:.4e} "
              f"+- {row['pst_stderr']:.2e} ({rel:.1%}; VOV {vov if vov is not None else float('nan'):.2g}){stop}"
              + (f"  [{row['flags'].replace(';', ', ')}: the error bar is not reliable]"
                 if {"unreliable_error", "target_not_reached"} & set(row["flags"].split(";")) else ""))
        heavy = row.get("heaviest_path")
        if heavy:
            print(f"         one ray holds {heavy['variance_share']:.0%} of its variance: {heavy['family']}")
            if heavy.get("hint"):
                print(f"         {heavy['hint']}")
    if len(res.pst) and not any(float(v) > 0 for v in res.pst):  # nothing reached the detector: say what blocks it
        from straylight.analyses.blockers import zero_light_hints

        hints = zero_light_hints(setup)
        print("no light reached the detector at any angle" + (": " if hints else
              " (no opaque optic or closed detector found; check the source's direction and the entrance)"))
        for hint in hints:
            print(f"  - {hint}")
    from straylight.checkpoints import PointStore

    PointStore.remove_folder(out / "pst.points")  # the sweep's results are written
    print(f"written {out}/{', '.join(written)}"
          + ("" if "pst.png" in written else " (one off-axis angle: no curve to plot; --plot draws its point)"))
    return 0
