"""The rig diagnosis on synthetic scans: speed (CONTRACTS §4.1) and the catalogue score tables.

    python benchmarks/diagnose_score.py --bench [--workers 2] [--repeats 1] [--seed 1]
    python benchmarks/diagnose_score.py --score-table [--strengths visible|limit|both] [--material NAME]
                                        [--only NAME ...] [--seed 1] [--workers 2]

``--bench``: a compact-plan scan (2 polarizations, 6 incidences, ~54 points per curve, from
:func:`rig.synth.synth_scan` with two injected effects, :data:`rig.synth.PAIRS` [1]) diagnosed with
every catalogue effect as a candidate, against a same-run baseline: the same scan diagnosed with
one candidate (``stray_background``), so the ratio is what the other nine candidates and the
forward selection cost on top of the baseline fit. Runs interleaved, best of ``--repeats``. Prints
wall and CPU seconds (this process and its worker processes), the phases of the full diagnosis,
its ratio to the one-candidate run and to the contract's one minute.

``--score-table``: each catalogue effect injected alone (and :data:`rig.synth.PAIRS`) at the
strengths of :data:`rig.synth.SCORE_CASES` (visible) and :data:`rig.synth.DETECTION_LIMIT_CASES`
(near the detection limit), on :func:`rig.points.score_plan`; one markdown row per case: the
injected effect's rank among the candidates, what was selected, the held-out gap before and after
and its ratio to the noise level (the tables of docs/diagnose.md §4).
"""
from __future__ import annotations

import argparse
import json
import resource
import time
from concurrent.futures import ProcessPoolExecutor

from rig.diagnose import diagnose
from rig.effects import build_effect
from rig.points import compact_plan
from rig.synth import DETECTION_LIMIT_CASES, PAIRS, SCORE_CASES, glossy_black, score_case, synth_scan, truth_material

CONTRACT_S = 60.0  # CONTRACTS §4.1: a paper-sized scan diagnosed in under a minute on 2 cores
BASELINE_EFFECTS = ("stray_background",)


def _cpu_s() -> float:
    """CPU seconds of this process and of its finished worker processes."""
    ch = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + ch.ru_utime + ch.ru_stime


def _timed(scan, workers: int, effects) -> dict:
    c0, w0 = _cpu_s(), time.perf_counter()
    d = diagnose(scan, effects=list(effects) if effects else None, workers=workers)
    return {"wall_s": time.perf_counter() - w0, "cpu_s": _cpu_s() - c0, "selected": list(d.selected),
            "phases_s": {k: round(v, 1) for k, v in d.timings.items()}}


def bench(workers: int = 2, seed: int = 1, repeats: int = 1) -> dict:
    """Best-of-``repeats`` times of the full diagnosis and of the one-candidate baseline (module doc)."""
    truth = [build_effect(n, **SCORE_CASES[n]) for n in PAIRS[1]]
    scan = synth_scan(glossy_black(), compact_plan(), truth, seed=seed, n_samples=1024)
    runs = {"baseline": [], "full": []}
    for _ in range(repeats):
        runs["baseline"].append(_timed(scan, workers, BASELINE_EFFECTS))
        runs["full"].append(_timed(scan, workers, None))
    best = {k: min(v, key=lambda r: r["wall_s"]) for k, v in runs.items()}
    full, base = best["full"], best["baseline"]
    return {"points": int(len(scan.brdf_per_sr)), "workers": workers, "repeats": repeats,
            "full": {**full, "wall_s": round(full["wall_s"], 1), "cpu_s": round(full["cpu_s"], 1)},
            "baseline": {"effects": list(BASELINE_EFFECTS), "wall_s": round(base["wall_s"], 1),
                         "cpu_s": round(base["cpu_s"], 1)},
            "full_over_baseline_wall": round(full["wall_s"] / base["wall_s"], 2),
            "full_over_baseline_cpu": round(full["cpu_s"] / base["cpu_s"], 2),
            "full_over_contract_minute": round(full["wall_s"] / CONTRACT_S, 2)}


def default_cases(strengths=None):
    """[(label, {name: params})]: clean, each catalogue effect alone, and :data:`rig.synth.PAIRS`."""
    strengths = SCORE_CASES if strengths is None else strengths
    return ([("clean", {})] + [(n, {n: p}) for n, p in strengths.items()]
            + [(f"{a} + {b}", {a: strengths[a], b: strengths[b]}) for a, b in PAIRS])


def score_table(cases=None, seed: int = 1, material=None, workers: int = 2, verbose: bool = False) -> str:
    """Markdown table: each case's injected effects, their ranks among the candidates when
    tried alone, what was selected, the held-out gap before/after, how much of it was closed
    and the final gap over the noise level, and the wall time (synthetic scan included).
    ``verbose`` prints each row as it is done."""
    cases = cases if cases is not None else default_cases()
    pool = ProcessPoolExecutor(max_workers=workers) if workers > 1 else None
    rows = ["| injected | rank of injected | selected | held-out gap before | after | noise | fall | after / noise | time (s) |",
            "|---|---|---|---|---|---|---|---|---|"]
    if verbose:
        print("\n".join(rows), flush=True)
    try:
        for label, effects in cases:
            t0 = time.perf_counter()
            _, _, doc = score_case(effects, seed=seed, material=material, workers=1, executor=pool)
            dt = time.perf_counter() - t0
            names = [c["name"] for c in doc["candidates"]]
            ranks = ", ".join(str(names.index(n) + 1) for n in effects) or "-"
            sel = ", ".join(doc["selected_effects"]) or "none"
            before, after = doc["baseline"]["heldout_gap"], doc["final"]["heldout_gap"]
            noise = doc["noise_level"]["heldout_gap"]
            rows.append(f"| {label} | {ranks} | {sel} | {before:.3f} | {after:.3f} | {noise:.3f} | "
                        f"{1 - after / before:.0%} | {after / noise:.2f} | {dt:.0f} |")
            if verbose:
                print(rows[-1], flush=True)
    finally:
        if pool is not None:
            pool.shutdown()
    return "\n".join(rows)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--score-table", action="store_true",
                        help="run the catalogue sweep at visible strengths and at the detection limit; print both tables")
    parser.add_argument("--bench", action="store_true", help="time one CONTRACTS 4.1-sized diagnosis against a "
                        "one-candidate baseline in the same run")
    parser.add_argument("--repeats", type=int, default=1, help="--bench: best of this many interleaved runs")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--material", default="glossy_black",
                        help="truth material: glossy_black (default), broad_black or a materials preset")
    parser.add_argument("--strengths", choices=("visible", "limit", "both"), default="both")
    parser.add_argument("--only", nargs="+", help="score only these cases (effect names or 'clean')")
    args = parser.parse_args(argv)
    if not (args.bench or args.score_table):
        parser.error("give --bench and/or --score-table")
    if args.bench:
        print(json.dumps(bench(args.workers, args.seed, args.repeats)))
    if args.score_table:
        mat = truth_material(args.material)
        tables = {"visible": SCORE_CASES, "limit": DETECTION_LIMIT_CASES}
        for key in (("visible", "limit") if args.strengths == "both" else (args.strengths,)):
            strengths = tables[key]
            cases = default_cases(strengths)
            if args.only:
                cases = [(n, {} if n == "clean" else {n: strengths[n]}) for n in args.only]
            elif key == "limit":
                cases = cases[1:]  # clean is the same scan in both tables
            print(f"\n{key} strengths, material {args.material}, seed {args.seed}:")
            score_table(cases, seed=args.seed, material=mat, workers=args.workers, verbose=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
