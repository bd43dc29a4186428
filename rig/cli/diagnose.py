"""``straylight rig diagnose``: compare a measured scan with the rig model and explain the gap
(CONTRACTS §4.1). Thin layer over :func:`rig.diagnose.diagnose`; ``rig`` is imported lazily."""
from __future__ import annotations

import os
import sys
from pathlib import Path


def add_parser(rig_subparsers) -> None:
    """Register ``diagnose`` under ``straylight rig`` (called by rig.cli)."""
    p = rig_subparsers.add_parser(
        "diagnose", help="sim-to-real diagnosis of a measured scan",
        description="Fit the sample's BRDF through the rig model on the training incidence angles, "
                    "then try every instrument effect of the catalogue (CONTRACTS §3) and report which "
                    "ones explain the measured-vs-simulated gap, checked on held-out incidence angles. "
                    "Method and rules: docs/diagnose.md.")
    p.add_argument("measured", metavar="MEASURED.csv", help="measured scan (CONTRACTS §2)")
    p.add_argument("--holdout-theta-i", metavar="DEG", type=float, nargs="+", dest="holdout_theta_i_deg",
                   help="incidence angles to hold out (default: the middle and the highest)")
    p.add_argument("--effects", metavar="NAME", nargs="+",
                   help="candidate effects (default: the whole catalogue)")
    p.add_argument("--json", required=True, metavar="OUT.json", help="write the result here")
    p.add_argument("--report", metavar="DIR", help="write plots, report.md and index.html here")
    p.add_argument("--workers", type=int, default=2, help="worker processes for the independent fits (default 2; 1 = serial)")
    p.add_argument("--seed", type=int, default=0,
                   help="recorded only: the diagnosis is deterministic (no random numbers)")
    p.set_defaults(func=run)


def run(args) -> int:
    import atomicio
    from materials.scan import read_scan
    from rig.diagnose import diagnose, to_json
    from rig.report import write_report

    if args.workers < 1:
        raise ValueError(f"--workers must be >= 1, got {args.workers}")
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    if not os.access(out.parent, os.W_OK):  # fail before a minute of fitting, not after
        raise PermissionError(f"--json {out}: folder {out.parent} is not writable")
    scan = read_scan(args.measured)
    if args.workers > 1:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(max_workers=args.workers) as pool:
            result = diagnose(scan, holdout_theta_i_deg=args.holdout_theta_i_deg, effects=args.effects,
                              progress=True, executor=pool)  # straylight.progress: a bar, or lines in a log
    else:
        result = diagnose(scan, holdout_theta_i_deg=args.holdout_theta_i_deg, effects=args.effects,
                          progress=True)
    doc = to_json(result)
    doc["measured"] = str(args.measured)
    doc["seed"] = args.seed
    atomicio.write_json(out, doc)
    if args.report:
        write_report(result, args.report, doc)
    sel = ", ".join(doc["selected_effects"]) or "none"
    print(f"held-out gap {doc['baseline']['heldout_gap']!s} -> {doc['final']['heldout_gap']!s} dex; "
          f"selected: {sel}; wrote {out}", file=sys.stderr)
    return 0
