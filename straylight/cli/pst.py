"""``straylight pst``: point source transmittance vs off-axis angle.

    straylight pst --builtin tube [--vanes N] --angles-deg 0 5 10 20 30 --rays N --seed S --out DIR
    straylight pst SCENE.toml [--entrance-center-mm X Y Z --entrance-radius-mm R] --angles-deg ... --out DIR

With a scene file, the beam is the file's first ``collimated_disk`` source: its disk (centre,
normal, radius, power) stays put and the ray direction is tilted off the disk normal.
Writes DIR/pst.csv, pst.json, pst.png (and entrance_ratio.png with an entrance).
"""
from __future__ import annotations

import math
from pathlib import Path


def add_common_scene_args(parser):
    """SCENE.toml or --builtin tube (+ tube overrides), used by pst, paths and view."""
    parser.add_argument("scene", nargs="?", help="scene TOML file (CONTRACTS §6)")
    parser.add_argument("--builtin", choices=("tube",), help="use the built-in baffled tube instead of a file")
    parser.add_argument("--vanes", type=int, default=None, help="built-in tube: number of vanes")
    parser.add_argument("--vane-inner-radius-mm", type=float, default=None, help="built-in tube: vane hole radius")
    parser.add_argument("--material", default=None, help="built-in tube: coating (preset or file; default z302_sample_b)")
    parser.add_argument("--detector", default=None, help="detector part name (default: the only detector)")


def add_parser(subparsers):
    p = subparsers.add_parser("pst", help="point source transmittance vs off-axis angle",
                              description=__doc__.splitlines()[0])
    add_common_scene_args(p)
    p.add_argument("--angles-deg", type=float, nargs="+", default=[0, 5, 10, 15, 20, 30, 45])
    p.add_argument("--azimuths-deg", type=float, nargs="+", default=[0.0])
    p.add_argument("--rays", type=int, default=200_000, help="rays per angle")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-nee", action="store_true", help="plain random walk (no next-event estimation)")
    p.add_argument("--entrance-center-mm", type=float, nargs=3, default=None)
    p.add_argument("--entrance-radius-mm", type=float, default=None)
    p.add_argument("--workers", type=int, default=None)
    p.add_argument("--scheduler", default=None, help="dask scheduler address")
    p.add_argument("--out", required=True, help="output directory")
    p.set_defaults(func=run)


def load_setup(args):
    """A :class:`straylight.analyses.builtin.Setup` from the common scene arguments."""
    from straylight.analyses.builtin import DEFAULT_MATERIAL, Beam, Entrance, Setup, tube_setup

    if (args.scene is None) == (args.builtin is None):
        raise ValueError("give either SCENE.toml or --builtin tube")
    if args.builtin:
        params = {}
        if args.vanes is not None:
            params["vane_count"] = args.vanes
        if args.vane_inner_radius_mm is not None:
            params["vane_inner_radius_mm"] = args.vane_inner_radius_mm
        setup = tube_setup(material=args.material or DEFAULT_MATERIAL, **params)
        if args.detector is not None:
            setup = Setup(setup.scene, setup.materials, setup.beam, setup.entrance, args.detector,
                          setup.description, setup.params)
        return setup
    from straylight.scene import load_scene

    rs = load_scene(args.scene)
    beams = [s for s in rs.sources if type(s).__name__ == "CollimatedDisk"]
    if not beams:
        raise ValueError(f"{args.scene}: no collimated_disk source to tilt for a PST sweep")
    src = beams[0]
    entrance = None
    if args.entrance_radius_mm is not None:
        center = args.entrance_center_mm if args.entrance_center_mm is not None else src.center_mm
        entrance = Entrance(center_mm=center, radius_mm=args.entrance_radius_mm)
    beam = Beam(center_mm=src.center_mm, axis=src.normal, radius_mm=src.radius_mm, power_w=src.power_w)
    return Setup(rs.scene, rs.materials, beam, entrance, args.detector, f"scene {args.scene}")


def run(args) -> int:
    import numpy as np

    from straylight.analyses.pst import pst_sweep

    setup = load_setup(args)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    res = pst_sweep(setup, np.radians(args.angles_deg), np.radians(args.azimuths_deg), n_rays=args.rays,
                    seed=args.seed, nee=not args.no_nee, workers=args.workers, scheduler=args.scheduler)
    res.write_csv(out / "pst.csv")
    res.write_json(out / "pst.json")
    res.plot(out / "pst.png")
    if setup.entrance is not None:
        res.plot(out / "entrance_ratio.png", quantity="entrance_ratio")
    for row in res.rows():
        rel = row["pst_stderr"] / row["pst"] if row["pst"] > 0 else math.nan
        print(f"{row['off_axis_deg']:6.2f} deg  az {row['azimuth_deg']:5.1f}  PST {row['pst']:.4e} "
              f"+- {row['pst_stderr']:.2e} ({rel:.1%})")
    print(f"written {out}/pst.csv, pst.json, pst.png")
    return 0
