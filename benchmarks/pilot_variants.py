"""What a cheaper entrance pilot costs the run: the pilot's CPU and the run's variance per variant.

    PYTHONPATH=$PWD:benchmarks .venv/bin/python benchmarks/pilot_variants.py --scene SCENE.toml
        [--variants as_is nee_split_64 ...] [--angles-deg 5 10 15 20 30 45 60] [--seeds 1 2 3 4 5 6]
        [--rays 100000] [--stream-set 0]

Each variant changes the entrance pilot only (straylight.engine.entrance_sampling: the estimator options
of :func:`~straylight.engine.entrance_sampling.pilot_estimator`, the pilot's ray count, its scatter's
polarization, or its streams: ``other_streams``, the control), then traces
each point as ``variance_paths.py`` does (the default set, the same per-point seed). Printed per variant
and angle: the pilot's CPU seconds, and over the seeds the median (mean) of CPU s x rel^2 (%^2) and of
rel^2 alone (the table's quality, which does not depend on the machine's load; the table serves every
angle, so look at all of them). The variants run in this process one after the other: CPU seconds compare
within one run only. ``--stream-set K`` moves every variant's pilot to other streams (K = 0: its own): at
angles where the table's own draw moves a row (5, 15 and 60 deg on the guide scope) compare variants over
several stream sets. docs/engine.md, "The pilot's cost", has the measurements.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

#: variant -> (estimator options the pilot changes, pilot rays or None for the module's PILOT_RAYS)
VARIANTS = {
    "as_is": ({}, None),
    "nee_split_64": ({"nee_split": 64}, None),  # the default set's own, the pilot before PILOT_NEE_SPLIT
    "no_nee_split": ({"nee_split": 1}, None),
    "no_tree_split": ({"tree_split": 1}, None),
    "no_specular_nee": ({"specular_nee": 0}, None),
    "none_of_the_three": ({"nee_split": 1, "tree_split": 1, "specular_nee": 0}, None),
    "roulette_1e-3": ({"rr_threshold": 1e-3}, None),
    "rays_2e4": ({}, 20_000),
    "unpolarized_scatter": ({}, None),  # the pilot's scatter vertices ignore the arriving polarization
    "other_streams": ({}, None),  # the same pilot on other streams: how far a table's own noise moves a row
    "uniform_rest": ({}, None),  # the rest of the pilot uniform, never guided (the pilot before its guided rest)
}
#: variant -> the entrance_sampling constants it sets
CONSTANTS = {
    "uniform_rest": {"PILOT_GUIDE_HITS": float("inf")},
}
OTHER_STREAMS = 1 << 36  # added to the pilot's first chunk by "other_streams" (and per --stream-set)


def _with_variant(name: str, stream_set: int = 0):
    """Patch the entrance pilot to variant ``name`` on the pilot's stream set ``stream_set`` (0: its
    own); returns the dict its timing goes to and the undo."""
    from straylight.engine import entrance_sampling as es

    changes, rays = VARIANTS[name]
    base, build = es.pilot_estimator, es.build_table
    seen: dict = {}
    constants = {k: getattr(es, k) for k in CONSTANTS.get(name, {})}
    for k, v in CONSTANTS.get(name, {}).items():
        setattr(es, k, v)

    def estimator(est):
        return replace(base(est), **changes)

    def timed(spec, run_batch, intersector=None, n_rays=es.PILOT_RAYS):
        c0 = time.process_time()
        table = build(spec, run_batch, intersector, rays or n_rays)
        seen["cpu_s"] = time.process_time() - c0
        seen["pilot_rays"] = 0 if table is None else table.pilot_rays
        return table

    es.pilot_estimator, es.build_table = estimator, timed
    offset = es.PILOT_CHUNK_OFFSET
    es.PILOT_CHUNK_OFFSET = offset + OTHER_STREAMS * (int(stream_set) * 2 + (name == "other_streams"))
    patched = []
    if name == "unpolarized_scatter":  # the scatter vertices' arriving polarization, in the pilot only
        from straylight.engine import specular_nee
        from straylight.engine.interactions import brdf_scatter

        for module in (specular_nee, brdf_scatter):
            def arriving(event, verts, frame, own=module.arriving):
                return None if event.spec.chunk_offset == es.PILOT_CHUNK_OFFSET else own(event, verts, frame)

            patched.append((module, module.arriving))
            module.arriving = arriving

    def undo():
        es.pilot_estimator, es.build_table, es.PILOT_CHUNK_OFFSET = base, build, offset
        for k, v in constants.items():
            setattr(es, k, v)
        for module, own in patched:
            module.arriving = own

    return seen, undo


def main(argv=None) -> int:
    import variance_paths

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", required=True)
    ap.add_argument("--variants", nargs="+", default=["as_is"], choices=tuple(VARIANTS))
    ap.add_argument("--angles-deg", type=float, nargs="+", default=[5, 10, 15, 20, 30, 45, 60])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5, 6])
    ap.add_argument("--rays", type=float, default=1e5)
    ap.add_argument("--stream-set", type=int, default=0,
                    help="the pilot's streams moved by 2 x this x 2^36 chunks (0: its own; a table's own noise)")
    args = ap.parse_args(argv)
    setup = variance_paths._setup(argparse.Namespace(builtin=False, newtonian=False, scene=args.scene))
    rows = []
    for name in args.variants:
        seen, undo = _with_variant(name, args.stream_set)
        try:
            for angle in args.angles_deg:
                runs = []
                for seed in args.seeds:
                    with contextlib.redirect_stdout(io.StringIO()):  # variance_paths' per-run report
                        r = variance_paths.run(setup, angle, seed, "default", int(args.rays), 1)
                    runs.append((r["cpu_s"], r["rel"] ** 2 * 1e4, seen.get("cpu_s", float("nan"))))
                    print(f"{name} {angle:g} deg seed {seed}: {r['cpu_s']:.2f} CPU s (pilot {runs[-1][2]:.2f}, "
                          f"{seen.get('pilot_rays', 0)} rays), "
                          f"rel. error {r['rel']:.2%}, VOV {r['vov']:.3g}", flush=True)
                rows.append((name, angle, runs))
        finally:
            undo()
    print("\n| variant | angle (deg) | pilot CPU s | CPU s x rel^2 (%^2) median (mean) | rel^2 median (mean) |\n"
          "|---|---|---|---|---|")
    for name, angle, runs in rows:
        work = [c * r2 for c, r2, _ in runs]
        rel2 = [r2 for _, r2, _ in runs]
        print(f"| {name} | {angle:g} | {statistics.median(p for *_, p in runs):.2f} | {statistics.median(work):.1f} "
              f"({statistics.mean(work):.1f}) | {statistics.median(rel2):.2f} ({statistics.mean(rel2):.2f}) |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
