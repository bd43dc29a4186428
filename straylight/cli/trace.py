"""``straylight trace SCENE.toml --rays N [--seed S] --json OUT.json [--workers K [--processes] | --scheduler ADDRESS]``.

CONTRACTS §4.3: traces a scene file and writes detector, absorbed and escaped powers with their
standard errors (plus the ledger) to OUT.json.
"""
from __future__ import annotations

import sys
import warnings

from straylight.cli.long_lived import long_lived_objects


def add_parser(subparsers) -> None:
    from straylight.engine.hurb import METHOD  # not .diffraction: the parser stays light (no numba)

    p = subparsers.add_parser("trace", help="Monte Carlo trace of a scene file (CONTRACTS §6)",
                              description="Trace a scene TOML and write powers with standard errors as JSON. "
                                          f"Edge diffraction (parts with diffraction = \"edges\", CONTRACTS §6.5): "
                                          f"{METHOD}, at the source's wavelength_nm (docs/diffraction.md).")
    p.add_argument("scene", metavar="SCENE.toml", help="scene file")
    from straylight.cli.pst import add_precision_args

    add_precision_args(p, what="number of rays")
    p.add_argument("--seed", type=int, default=0, help="random seed (same seed, same numbers)")
    p.add_argument("--json", required=True, metavar="OUT.json", help="where to write the result")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=None, help="dask LocalCluster with K worker threads (K processes with --processes)")
    where.add_argument("--scheduler", default=None, metavar="ADDRESS", help="dask scheduler address")
    where.add_argument("--threads", type=int, default=None,
                       help="K threads in this process (embree and the kernels release the GIL; "
                            "often the fastest choice on one machine)")
    p.add_argument("--no-nee", action="store_true", help="disable next-event estimation toward detectors")
    p.add_argument("--vertex-sampling", choices=("auto", "on", "off"), default="auto",
                   help="first-vertex area sampling for single-scatter paths, combined with the walk by MIS "
                        "(docs/engine.md); auto: on with NEE and exactly one collimated or point source")
    p.add_argument("--scatter-polarization", choices=("auto", "on"), default="auto",
                   help="auto: scattered light keeps a polarization only where the light arriving was "
                        "polarized (linear source, Fresnel interface); on: also the partial polarization "
                        "that scatter creates from unpolarized light (slower; docs/engine.md)")
    from straylight.cli.diffraction_args import add_diffraction_arg

    add_diffraction_arg(p)
    p.add_argument("--max-events", type=int, default=1000, help="surface events per ray (default 1000)")
    p.add_argument("--batch-rays", type=int, default=None,
                   help="rays per batch in memory (default: automatic; no effect on results)")
    from straylight.cli.cluster_args import add_cluster_args

    add_cluster_args(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from straylight.cli.cluster_args import start_early

    start_early(args)  # worker processes: their fork server loads while the scene loads
    from straylight.scene import SceneWarning, load_scene
    from straylight.cli.pst import precision_from_args
    from straylight.trace import EstimatorOptions, PhysicsOptions, TraceOptions

    precision = precision_from_args(args)
    if precision is None and args.rays < 1:
        raise ValueError(f"--rays must be >= 1, got {args.rays}")
    if args.workers is not None and args.workers < 1:
        raise ValueError(f"--workers must be >= 1, got {args.workers}")
    if args.threads is not None and args.threads < 1:
        raise ValueError(f"--threads must be >= 1, got {args.threads}")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", SceneWarning)
        with long_lived_objects("scene"):  # numba's start and the scene live as long as the command
            rs = load_scene(args.scene)
    for w in caught:
        print(f"straylight: warning: {w.message}", file=sys.stderr)
    from straylight.engine.first_vertex import unsupported

    vertex = {"on": True, "off": False}.get(args.vertex_sampling)
    if vertex is None:
        vertex = not args.no_nee and unsupported(tuple(rs.sources)) is None
    # progress: a bar on a terminal, a plain line every few seconds in a log (straylight.progress)
    options = TraceOptions(estimator=EstimatorOptions(nee=not args.no_nee, first_vertex_sampling=vertex),
                           physics=PhysicsOptions(max_events=args.max_events,
                                                  scatter_polarization=args.scatter_polarization,
                                                  diffraction="scene" if args.diffraction == "on" else "off"),
                           batch_rays=args.batch_rays)
    from straylight.cli.cluster_args import execution

    with execution(args) as ex:
        return _run(args, rs, options, precision, ex)


def _run(args, rs, options, precision, ex) -> int:
    import atomicio
    from straylight.trace import trace

    if precision is None:
        res = trace(rs.scene, rs.sources, args.rays, args.seed, materials=rs.materials, options=options,
                    execution=ex)
        doc = res.to_json_dict()
    else:
        from straylight.analyses.precision import trace_to_precision

        if not any(p.role == "detector" for p in rs.scene.parts):
            raise ValueError(f"{args.scene}: --target-rel-error needs a detector part (its power is the target)")
        run = trace_to_precision(rs.scene, rs.sources, args.seed, precision, materials=rs.materials,
                                 options=options, execution=ex,
                                 on_round=lambda msg: print(f"straylight: trace: {msg}", file=sys.stderr))
        doc = run.result.to_json_dict()
        doc["precision"] = {"target_rel_error": precision.target_rel_error, "max_rays": int(precision.max_rays),
                            "max_seconds": precision.max_seconds if precision.max_seconds != float("inf") else None,
                            "max_vov": precision.max_vov, **run.summary()}
        print(f"straylight: trace: stopped by {run.stop_reason} after {run.result.n_rays} rays "
              f"({run.seconds:.1f} s)", file=sys.stderr)
    atomicio.write_json(args.json, doc)
    return 0
