"""``straylight design vanes``: design the vanes of a cylindrical baffle tube (CONTRACTS 4.6).

    straylight design vanes --tube-radius-mm 50 --tube-length-mm 300 --stop-radius-mm 35 \\
        --field-deg 0 --exclusion-deg 20 --out design_out

Writes DIR/design.json, DIR/scene.toml (+ meshes), DIR/design.step and DIR/index.html.
"""
from __future__ import annotations

import time

CLOCK_SLACK_S = 0.05  # file times come from the kernel's coarse clock, a few ms behind time.time()
DESIGN_OUTPUTS = ("*.toml", "*.stl", "*.ply", "*.obj", "*.step", "*.json", "*.html", "*.png")  # what --out holds


def add_parser(subparsers):
    p = subparsers.add_parser("design", help="design baffle vanes (construction + Monte Carlo refinement)",
                              description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="design_command", metavar="WHAT", required=True)
    v = sub.add_parser("vanes", help="vanes of a cylindrical tube: Freniere construction, then PST refinement",
                       description="Vanes of a cylindrical tube (docs/design.md). Frame: axis z, wall r = R for "
                                   "0 <= z <= L, entrance z = L, detector r <= S at z = 0.")
    v.add_argument("--tube-radius-mm", type=float, required=True, help="R: wall inner radius")
    v.add_argument("--tube-length-mm", type=float, required=True, help="L: detector plane to entrance")
    v.add_argument("--stop-radius-mm", type=float, required=True, help="S: detector / aperture stop radius")
    v.add_argument("--field-deg", type=float, required=True, help="F: field half-angle that must not vignette")
    v.add_argument("--exclusion-deg", type=float, required=True, help="E: off-axis angle beyond which to reject")
    v.add_argument("--vane-thickness-mm", type=float, default=1.0)
    v.add_argument("--bevel-deg", type=float, default=0.0, help="bevel of the vane edge (knife edge), deg")
    v.add_argument("--bevel-side", choices=("back", "front"), default="back",
                   help="face the bevel is on: back = toward the detector (knife edge toward the entrance)")
    v.add_argument("--max-vanes", type=int, default=30)
    v.add_argument("--keep-out-mm", type=float, nargs=2, action="append", metavar=("Z_LO", "Z_HI"), default=[],
                   help="no vane between these heights (repeatable)")
    v.add_argument("--material", default="z302_sample_b", help="coating: preset name or material file")
    v.add_argument("--rays", type=int, default=100_000, help="rays per angle for the PST in design.json")
    v.add_argument("--refine-rays", type=int, default=None, help="rays per angle in the optimiser (default rays/5)")
    v.add_argument("--refine-evals", type=int, default=40, help="optimiser budget in traced layouts (0: no refinement)")
    v.add_argument("--optimise", action="store_true",
                   help="also choose the bevel (angle and side) by the Monte Carlo objective, at the construction's "
                        "vane count (docs/design.md)")
    v.add_argument("--seed", type=int, default=0)
    v.add_argument("--threads", type=int, default=2, help="tracing threads")
    v.add_argument("--out", required=True, help="output directory")
    v.add_argument("--force", action="store_true",
                   help="overwrite files in --out that straylight did not write or that were changed by hand")
    v.add_argument("--resume", action="store_true",
                   help="continue an interrupted run in the same --out: finished final PST points are read back")
    v.set_defaults(func=run)
    b = sub.add_parser("baffles", help="light shields of a two-mirror telescope: exact construction + trace check",
                       description="Primary tube, secondary skirt (and collar, rear enclosure) of a Cassegrain-type "
                                   "telescope so that no direct ray from outside the half-field reaches the image "
                                   "(docs/baffles.md).")
    b.add_argument("scene", help="the telescope's scene TOML (CONTRACTS 6 / 6.1, or from `straylight optics import`)")
    b.add_argument("--field-deg", type=float, required=True, help="F: half-field that must not be vignetted, deg")
    b.add_argument("--max-added-obscuration", type=float, default=0.05,
                   help="largest obscuration the shields may add, fraction of the aperture area (default 0.05)")
    b.add_argument("--material", default="z302_sample_b", help="coating of the shields (preset or material file)")
    b.add_argument("--rays", type=int, default=20_000, help="rays per angle in the direct-path check and the PST")
    b.add_argument("--seed", type=int, default=0)
    b.add_argument("--refine-rays", type=int, default=5_000,
                   help="rays per angle for the Monte Carlo choice among feasible layouts")
    b.add_argument("--no-refine", action="store_true", help="keep the construction (no Monte Carlo choice)")
    b.add_argument("--no-step", action="store_true", help="do not write DIR/baffles.step")
    b.add_argument("--out", required=True, help="output directory")
    b.add_argument("--force", action="store_true",
                   help="overwrite files in --out that straylight did not write or that were changed by hand")
    b.set_defaults(func=run_baffles)


def run_baffles(args) -> int:
    import sys

    from atomicio.guard import check_overwrite, record_outputs
    from straylight.design.baffles import design_baffles
    from straylight.design.shields import NoShieldError

    if args.rays < 1:
        raise ValueError(f"--rays must be >= 1, got {args.rays}")
    check_overwrite(args.out, patterns=DESIGN_OUTPUTS, force=args.force)
    try:
        doc = design_baffles(args.scene, args.field_deg, args.out, max_added_obscuration=args.max_added_obscuration,
                             material=args.material, rays=args.rays, seed=args.seed, step=not args.no_step,
                             refine_rays=0 if args.no_refine else args.refine_rays)
    except NoShieldError as exc:
        print(f"straylight design baffles: {exc}", file=sys.stderr)
        return 1
    record_outputs(args.out, patterns=DESIGN_OUTPUTS)
    dc = doc["direct_check"]
    for p in doc["baffles"]:
        print(f"  {p['name']:24s} {p['shape']}")
    print(f"obscuration {doc['obscuration_before']:.4f} -> {doc['obscuration_after']:.4f} "
          f"(added {doc['obscuration_added']:.4f}); direct paths from 2F to 10 deg: "
          f"{'none' if dc['blocked'] else 'SOME REMAIN'}; on-axis throughput ratio "
          f"{dc['on_axis_throughput_ratio'] if dc['on_axis_throughput_ratio'] is None else round(dc['on_axis_throughput_ratio'], 4)}")
    print(f"written {args.out}/scene.toml, scene_unshielded.toml, design.json, index.html, view.html"
          + ("" if args.no_step else ", baffles.step"))
    return 0


def _optimised_bevel(spec, args, ex):
    """The spec with the bevel (angle, side) of lowest CRN objective at the construction's positions."""
    from straylight.design import model
    from straylight.design.optimise import optimise_vanes
    from straylight.design.vanes import band_angles, optimiser_seed

    _, _, mats = model.coating(args.material)
    rays = int(args.refine_rays or max(2_000, int(args.rays) // 5))
    res = optimise_vanes(spec, mats, band_angles(spec), rays=rays, seed=optimiser_seed(args.seed), max_evals=0,
                         execution=ex)
    for t in res.tried:
        j = "none" if t["objective"] is None else f"{t['objective']:.3f}"
        print(f"  bevel {t['bevel_deg']:4.0f} deg {t['bevel_side']:5s}  J {j}")
    print(f"optimiser: bevel {res.spec.bevel_deg:g} deg {res.spec.bevel_side} (J {res.start_objective:.3f} -> "
          f"{res.best_objective:.3f} +- {res.start_objective_stderr:.3f})")
    return res.spec


def run(args) -> int:
    from straylight.design.construction import BaffleSpec
    from straylight.design.vanes import design_vanes

    spec = BaffleSpec(args.tube_radius_mm, args.tube_length_mm, args.stop_radius_mm, args.field_deg,
                      args.exclusion_deg, args.vane_thickness_mm, args.bevel_deg, args.bevel_side, args.max_vanes,
                      tuple(tuple(k) for k in args.keep_out_mm))
    for name in ("rays", "threads"):
        if getattr(args, name) < 1:
            raise ValueError(f"--{name} must be >= 1, got {getattr(args, name)}")
    if args.refine_evals < 0:
        raise ValueError(f"--refine-evals must be >= 0, got {args.refine_evals}")
    from atomicio.guard import check_overwrite, record_outputs

    # a resume too: a design.json or scene.toml the user edited since is theirs (--force replaces it)
    check_overwrite(args.out, patterns=DESIGN_OUTPUTS, force=args.force)
    from straylight.cli.cluster_args import execution

    started = time.time() - CLOCK_SLACK_S
    try:
        with execution(args) as ex:  # --threads K in this process
            if args.optimise:
                spec = _optimised_bevel(spec, args, ex)
            doc = design_vanes(spec, args.out, material=args.material, rays=args.rays, seed=args.seed,
                               refine_rays=args.refine_rays, refine_evals=args.refine_evals, execution=ex,
                               resume=args.resume)
    finally:  # what this run wrote, even if interrupted, is its own: a --resume may replace it
        record_outputs(args.out, patterns=DESIGN_OUTPUTS, since=started)
    print(f"{len(doc['vanes'])} vanes ({doc['design_source']}):")
    for v in doc["vanes"]:
        print(f"  z {v['z_mm']:8.2f} mm  inner radius {v['inner_radius_mm']:7.3f} mm")
    for d, r in zip(doc["pst"], doc["ratio_to_baseline"]):
        ratio = "" if r["ratio"] is None else f"  design / evenly spaced {r['ratio']:.3f} +- {r['ratio_stderr']:.3f}"
        print(f"{d['off_axis_deg']:6.2f} deg  PST {d['pst']:.4e} +- {d['pst_stderr']:.2e}{ratio}")
    print(f"written {args.out}/design.json, scene.toml, design.step, index.html")
    return 0
