"""``straylight rig``: scan (CONTRACTS §4.4), diagnose (rig.cli.diagnose) and twin (rig.cli.twin).

Registered with the ``straylight`` command through the entry point ``rig = "rig.cli:add_parser"``
of the group ``straylight.commands`` (pyproject.toml), so straylight never imports rig.
Thin layer: parse, build the simulated or real instrument, call :func:`rig.run.run_scan`.
The instrument modules are imported inside the commands, so building the parser never pulls in
bluesky.
"""
from __future__ import annotations

import sys

from rig.cli import diagnose as diagnose_command
from rig.cli import twin as twin_command


def add_parser(subparsers) -> None:
    rig = subparsers.add_parser("rig", help="bidirectional reflectometer: scans and sim-to-real diagnosis")
    rig_sub = rig.add_subparsers(dest="rig_command", metavar="RIG_COMMAND")
    rig.set_defaults(func=lambda args: (rig.print_help(), 2)[1])

    scan = rig_sub.add_parser(
        "scan", help="run a reflectometer scan and write the CSV as it goes",
        description="Run a BRDF scan on the simulated (--sim) or real (--hardware CONFIG) reflectometer. "
                    "Writes SCAN.csv (CONTRACTS §2) after every point and every bluesky document to "
                    "SCAN.log.jsonl. Ctrl-C/SIGTERM stop cleanly; --resume continues the same file.")
    backend = scan.add_mutually_exclusive_group(required=True)
    backend.add_argument("--sim", action="store_true", help="simulated instrument (rig model + noise)")
    backend.add_argument("--hardware", metavar="CONFIG", help="TOML/JSON naming the VISA resources (docs/rig.md)")
    scan.add_argument("--sample", metavar="NAME|MODEL.json",
                      help="material preset or file (--sim), or the sample's id (--hardware); "
                           "not needed for a signature plan")
    scan.add_argument("--plan", default="paper", metavar="paper|signature|PLAN.json",
                      help="'paper' (seed paper's plan, default), 'signature' (paper grid, no sample) or a PLAN.json")
    scan.add_argument("-o", "--output", required=True, metavar="SCAN.csv", help="scan CSV to write")
    scan.add_argument("--seed", type=int, default=0, help="seed of the simulated noise (default 0)")
    scan.add_argument("--resume", action="store_true", help="continue an interrupted scan in the same file")
    scan.add_argument("--log", metavar="LOG.jsonl", help="document log (default: SCAN.log.jsonl next to the CSV)")
    scan.add_argument("--effect", action="append", default=[], metavar="NAME[:KEY=VALUE,...]",
                      help="--sim only: inject an instrument effect of CONTRACTS §3 into the simulated "
                           "rig, e.g. angle_offset:offset_deg=0.1 (repeatable; recorded in the log only)")
    scan.add_argument("--fsync", action="store_true",
                      help="--sim: fsync the CSV and log after every point (always on with --hardware)")
    scan.add_argument("--ideal", action="store_true",
                      help="--sim only: read the material BRDF itself (no slit/beam averaging)")
    scan.set_defaults(func=run_scan_command)

    diagnose_command.add_parser(rig_sub)
    twin_command.add_parser(rig_sub)


def run_scan_command(args) -> int:
    import logging
    from dataclasses import replace

    bluesky_log = logging.getLogger("bluesky")
    if not getattr(args, "debug", False) and not bluesky_log.handlers:
        # bluesky logs an aborted run (Ctrl-C, SIGTERM) with a traceback that logging's last-resort
        # handler prints to stderr; the interruption is reported below in one line instead
        bluesky_log.addHandler(logging.NullHandler())

    from atomicio.guard import check_output_file

    if args.seed is not None and args.seed < 0:  # before any file is made (a bad seed left an empty scan to resume)
        raise ValueError(f"--seed must be a non-negative integer, got {args.seed}")
    check_output_file(args.output, "-o scan")  # before any device moves
    if args.log:
        check_output_file(args.log, "--log")
    from rig.plans import load_plan, paper_plan_spec
    from rig.run import hardware_instrument, load_hardware_config, run_scan, sim_instrument

    spec = replace(paper_plan_spec(), name="signature", signature=True) if args.plan == "signature" \
        else load_plan(args.plan)
    if spec.signature:
        sample_label = "none (instrument signature)"
    elif not args.sample:
        raise ValueError("--sample is required (a preset name or MODEL.json) unless the plan is a signature scan")
    else:
        sample_label = args.sample
    nominal_w = None
    if args.sim:
        effects = [parse_effect(text) for text in args.effect]
        if effects and args.ideal:
            raise ValueError("--effect needs the rig model: drop --ideal")
        sim, devices = sim_instrument(None if spec.signature else args.sample, seed=args.seed, ideal=args.ideal,
                                      effects=effects)
        config, gain = sim.config, sim.gain_v_per_w
        md = {"backend": "sim", "seed": args.seed, "ideal": args.ideal, "sim_effects": list(args.effect)}
        if not spec.signature:
            sample_label = getattr(sim.material, "name", None) or args.sample
    else:
        if args.ideal or args.effect:
            raise ValueError("--ideal and --effect apply to --sim only")
        hw = load_hardware_config(args.hardware)
        config, devices, gain = hardware_instrument(hw)
        md = {"backend": "hardware", "hardware_config": str(args.hardware)}
        nominal_w = hw.get("laser_nominal_w")
    outcome = run_scan(devices, spec, args.output, sample=sample_label, config=config, md=md,
                       resume=args.resume, progress=True, log_path=args.log, gain_v_per_w=gain,
                       fsync=bool(args.hardware) or args.fsync, nominal_power_w=nominal_w)
    saved = f"{outcome.n_points_in_file} of {outcome.n_points_plan} points in {outcome.csv_path}"
    if outcome.exit_status == "abort":
        print(f"straylight: scan {outcome.reason}: {saved}; continue with --resume", file=sys.stderr)
        return 130
    print(f"scan complete: {saved} (log {outcome.log_path})", file=sys.stderr)
    return 0


def parse_effect(text: str):
    """``'angle_offset:offset_deg=0.1,...'`` -> ``rig.effects.build_effect(...)``."""
    from rig.effects import build_effect

    name, _, rest = text.partition(":")
    params = {}
    for item in filter(None, (p.strip() for p in rest.split(","))):
        key, eq, value = item.partition("=")
        if not eq:
            raise ValueError(f"--effect {text!r}: expected NAME:KEY=VALUE[,KEY=VALUE], got {item!r}")
        try:
            params[key.strip()] = float(value)
        except ValueError:
            raise ValueError(f"--effect {text!r}: {key.strip()} = {value!r} is not a number") from None
    return build_effect(name.strip(), **params)
