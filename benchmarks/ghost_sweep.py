"""What a user meets running ``optics import`` then ``ghosts`` on lens files nobody tried (CONTRACTS 8.1, 8.3, 8.4).

    .venv/bin/python benchmarks/ghost_sweep.py --odb /path/to/OpticsDatabase [--seq-dir DIR ...] [--count 40]
        [--seed 2026] [--max-seconds 20] [--jobs 2] [--focus] [--work /tmp/ghost_sweep] [--no-write]

Picks ``--count`` Zemax files of an OpticsDatabase checkout (https://github.com/amegahed/OpticsDatabase, its
``Optics`` folder) with a fixed seed: a few catadioptric lenses (mirrors written as index -1), a few cemented
doublets and triplets (``Achromats``, ``Components``, ``Astronomy/Objectives``), a few whose surfaces name a
coating (``COAT``), the rest among the lenses of 4-20 optical surfaces; files already in tests/data/lenses are
left out. Adds every CODE V ``.seq`` of ``--seq-dir`` (default: rayoptics' ``codev/tests`` in the running
Python, and tests/data/lenses), one per content. The chosen list is written to WORK/files.txt.

For each file, as separate commands (``python -m straylight.cli.main``): ``optics info LENS``, ``optics import
LENS --out WORK/<n>/import`` and ``ghosts WORK/<n>/import/scene.toml --max-seconds S --out WORK/<n>/ghosts``
(default seed and order). Records per file (WORK/results.jsonl, one JSON line each; a rerun skips the files
already there): exit codes and wall seconds, the refusal's one line, the warnings on stderr, any Python traceback,
whether ghosts.json is strict JSON (no NaN / Infinity), the number of ghosts, nulls where CONTRACTS 8.4 wants a
number (power and error of a traced ghost, radius, peak ratio; ``focus_mm`` may be null for a collimated ghost),
the nominal image's power (a 1 W source: zero or above 1 W is a problem) and whether the files written are
ghosts.csv, ghosts.json, ghosts.md, ghosts.png. ``--focus``: also tests/test_optics_focus.py's on-axis check (the
imported scene's power near the file's own sequential focus, rayoptics' trace: >= 0.95 of it within 1.2 x the
sequential spot's radius, else a problem). Prints a table (one row per file, problems named) and the counts,
and puts them in benchmarks/RESULTS.md, section ghost_sweep (``--no-write``: print only).
"""
from __future__ import annotations

import argparse
import concurrent.futures
import hashlib
import json
import math
import os
import random
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

GHOST_FILES = ("ghosts.csv", "ghosts.json", "ghosts.md", "ghosts.png")
MIRROR = re.compile(r"^\s*GLAS\s+(MIRROR\b|\S+\s+\S+\s+\S+\s+-1(\.0*)?\s)", re.M)


def _text(path: Path) -> str:
    b = path.read_bytes()
    if b[:2] in (b"\xff\xfe", b"\xfe\xff"):
        return b.decode("utf-16", "replace")
    return b.decode("utf-8", "replace")


# lens files this sweep found wrong, then added to tests/data/lenses: still drawn, so the draw stays the same
ADDED_FROM_THIS_SWEEP = ("Samyang_50mm_F1.4_AS_UMC", "Canon_New_FD_500mm_f8_Mirror", "Nikon_AI_Reflex-Nikkor_1000mm_f11")


def _tested_names() -> set:
    """Names (lower case, spaces, underscores and parentheses dropped) of the lens files already in
    tests/data/lenses when the sweep was written."""
    return {re.sub(r"[\s_()]", "", p.stem).lower() for p in (ROOT / "tests" / "data" / "lenses").rglob("*.*")
            if p.stem not in ADDED_FROM_THIS_SWEEP}


def pick_zemax(odb: Path, count: int, seed: int) -> list:
    """``count`` Zemax files of the OpticsDatabase ``odb``: 4 catadioptric, 5 cemented, 2 coated, the rest of
    4-20 optical surfaces, by ``random.Random(seed)`` over the sorted list."""
    rng = random.Random(seed)
    tested = _tested_names()
    files = sorted(p for p in odb.rglob("*") if p.suffix.lower() == ".zmx"
                   and re.sub(r"[\s_()]", "", p.stem.replace("-Zemax(ZMX)", "")).lower() not in tested)
    info = {}
    for p in files:
        t = _text(p)
        info[p] = {"surfaces": max(len(re.findall(r"^SURF\s", t, re.M)) - 2, 0), "mirror": bool(MIRROR.search(t)),
                   "coat": bool(re.search(r"^\s*COAT\s+\S", t, re.M))}
    rel = {p: p.relative_to(odb).as_posix() for p in files}
    mirror = [p for p in files if info[p]["mirror"]]
    cemented = [p for p in files if re.search(r"(^|/)(Achromats|Components|Astronomy/Objectives)/", rel[p])
                and not info[p]["mirror"]]
    coated = [p for p in files if info[p]["coat"] and p not in cemented and not info[p]["mirror"]]
    chosen: list = []

    def take(pool, k):
        pool = [p for p in pool if p not in chosen]
        chosen.extend(rng.sample(pool, min(k, len(pool))))

    take(mirror, 4)
    take(cemented, 5)
    take(coated or [p for p in files if info[p]["coat"]], 2)
    take([p for p in files if 4 <= info[p]["surfaces"] <= 20 and not info[p]["mirror"]], count - len(chosen))
    return [(p, info[p]) for p in chosen]


def seq_files(dirs) -> list:
    seen, out = set(), []
    for d in dirs:
        for p in sorted(Path(d).rglob("*.seq")):
            h = hashlib.sha256(p.read_bytes()).hexdigest()
            if h not in seen:
                seen.add(h)
                out.append(p)
    return out


def _strict_json(path: Path):
    def bad(c):
        raise ValueError(f"non-strict JSON constant {c}")
    try:
        return json.loads(path.read_text(encoding="utf-8"), parse_constant=bad), None
    except (OSError, ValueError) as e:
        return None, str(e)


def _run(cmd, timeout):
    env = dict(os.environ, PYTHONPATH=str(ROOT), MPLBACKEND="Agg")
    t0 = time.perf_counter()
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env, cwd=str(ROOT))
        return r.returncode, time.perf_counter() - t0, r.stdout, r.stderr
    except subprocess.TimeoutExpired as e:
        return None, time.perf_counter() - t0, e.stdout or "", (e.stderr or "") if isinstance(e.stderr, str) else ""


def _stderr_lines(err: str) -> tuple:
    lines = [x.rstrip() for x in err.splitlines() if x.strip()]
    tb = any(x.startswith("Traceback") for x in lines)
    warnings = [x for x in lines if "warning" in x.lower()[:40]]
    return lines, warnings, tb


FOCUS = """
import json, sys, tempfile
from pathlib import Path
sys.path.insert(0, sys.argv[2])
from test_optics_focus import focus_check
try:
    inside, ee_scene, ee_seq, r_geo = focus_check(Path(sys.argv[1]), 0.0, Path(tempfile.mkdtemp()))
    print(json.dumps({"inside": inside, "ee_scene": ee_scene, "ee_seq": ee_seq, "r_geo_mm": r_geo}))
except AssertionError as e:
    print(json.dumps({"error": ("at most 50 of ~3000 sequential rays pass (too few to check)" if "len(seq)" in repr(e)
                                or not str(e) else str(e))[:160]}))
"""


def focus_check(lens: Path, timeout: float) -> dict:
    """tests/test_optics_focus.py's check on axis: of the imported scene's power near the sequential focus
    (rayoptics' real-ray trace of the file), the fraction within 1.2 x the sequential spot's radius."""
    rc, s, out, err = _run([sys.executable, "-c", FOCUS, str(lens), str(ROOT / "tests")], timeout)
    try:
        return {**json.loads(out.strip().splitlines()[-1]), "seconds": round(s, 1)}
    except (ValueError, IndexError):
        return {"error": f"exit {rc}: " + (err.strip().splitlines() or [""])[-1][:160], "seconds": round(s, 1)}


def sweep_one(lens: Path, work: Path, max_seconds: float, timeout: float, focus: bool = False) -> dict:
    py = sys.executable
    cli = [py, "-m", "straylight.cli.main"]
    rec: dict = {"file": str(lens), "work": str(work), "problems": []}
    problems = rec["problems"]
    rc, s, out, err = _run(cli + ["optics", "info", str(lens)], timeout)
    lines, _, tb = _stderr_lines(err)
    rec["info"] = {"rc": rc, "seconds": round(s, 2), "stderr": lines[-3:]}
    if tb:
        problems.append("info: traceback")
    imp = work / "import"
    rc, s, out, err = _run(cli + ["optics", "import", str(lens), "--out", str(imp)], timeout)
    lines, warns, tb = _stderr_lines(err)
    rec["import"] = {"rc": rc, "seconds": round(s, 2), "stdout": out.strip().splitlines()[-1:] if out else [],
                     "stderr": lines[-5:], "warnings": warns}
    if tb:
        problems.append("import: traceback")
    if (rc == 0) != (rec["info"]["rc"] == 0):
        problems.append(f"info rc {rec['info']['rc']} but import rc {rc}")
    if rc != 0:
        rec["refused"] = lines[-1] if lines else f"exit {rc}, nothing on stderr"
        if len([x for x in lines if not x.startswith("warning")]) > 1:
            problems.append("import: refusal of more than one line")
        return rec
    pres, bad = _strict_json(imp / "prescription.json")
    if bad:
        problems.append(f"prescription.json: {bad}")
    elif pres is not None:
        rec["optical_surfaces"] = len(pres.get("surfaces", []))
        rec["efl_mm"] = pres.get("efl_mm")
    if focus:
        rec["focus"] = focus_check(lens, timeout)
        f = rec["focus"]
        if "inside" in f and f["inside"] < 0.95:
            problems.append(f"nominal image off the sequential focus ({f['inside']:.2f} of the power within 1.2 x the "
                            "sequential spot)")
    gdir = work / "ghosts"
    rc, s, out, err = _run(cli + ["ghosts", str(imp / "scene.toml"), "--max-seconds", str(max_seconds),
                                  "--out", str(gdir)], timeout)
    lines, warns, tb = _stderr_lines(err)
    rec["ghosts"] = {"rc": rc, "seconds": round(s, 2), "stderr": [x for x in lines if x not in warns][-5:],
                     "warnings": warns}
    if rc is None:
        problems.append(f"ghosts: killed after {timeout:g} s")
        return rec
    if tb:
        problems.append("ghosts: traceback")
    if rc != 0:
        rec["ghosts"]["refused"] = lines[-1] if lines else f"exit {rc}"
        return rec
    return rec


def check_tables(rec: dict, gdir: Path) -> None:
    """The checks of a ghost table written in ``gdir`` (re-read at every report): files, strict JSON, nulls where
    CONTRACTS 8.4 wants numbers, the nominal image. Adds to ``rec["ghosts"]`` and ``rec["table_problems"]``."""
    problems = rec["table_problems"] = []
    g = rec["ghosts"]
    written = sorted(p.name for p in gdir.iterdir()) if gdir.is_dir() else []
    g["written"] = written
    missing = [f for f in GHOST_FILES if f not in written]
    if missing:
        problems.append("ghosts: missing " + ", ".join(missing))
    table, bad = _strict_json(gdir / "ghosts.json")
    if bad or table is None:
        problems.append(f"ghosts.json: {bad}")
        return
    rows = table.get("ghosts", [])
    nominal = table.get("nominal", {})
    g.update({"count": len(rows), "nominal_w": nominal.get("power_w"), "nominal_radius_mm": nominal.get("radius_mm"),
              "nominal_focus_mm": nominal.get("focus_mm"), "table_seconds": table.get("seconds"),
              "untraced": sum(1 for r in rows if not r.get("rays")),
              "no_ray": sum(1 for r in rows if r.get("upper_w") is not None)})
    pw = nominal.get("power_w")
    if not isinstance(pw, (int, float)) or not 0 < pw <= 1.0 + 1e-9:
        problems.append(f"nominal image power {pw}")
    nulls: dict = {}
    for r in rows:
        if not r.get("rays"):  # untraced (time cap): nulls are the contract's
            continue
        arrived = r.get("upper_w") is None  # a ghost no ray reached has no spot: radius / focus may be null
        for k in ("power_w", "stderr_w", "fraction_of_nominal", "peak_ratio") + (("radius_mm",) if arrived else ()):
            v = r.get(k)
            if v is None or (isinstance(v, float) and not math.isfinite(v)):
                nulls[k] = nulls.get(k, 0) + 1
    if nulls:
        problems.append("nulls in traced ghosts: " + ", ".join(f"{k} x{v}" for k, v in sorted(nulls.items())))
    return rec


def _group(label: str, info) -> str:
    if info is None:
        return "CODE V (rayoptics' tests, tests/data/lenses)"
    if info["mirror"]:
        return "OpticsDatabase catadioptric"
    if re.search(r"^odb:(Achromats|Components|Astronomy/Objectives)/", label):
        return "OpticsDatabase cemented doublets / triplets (Edmund's coated)"
    return "OpticsDatabase lenses of 4-20 surfaces"


def _row(rec: dict, label: str) -> str:
    imp = rec.get("import", {})
    g = rec.get("ghosts", {})
    if imp.get("rc") != 0:
        status = "refused: " + (rec.get("refused") or "").split(": ", 1)[-1][:90]
        return f"| {label} | - | {status} | | | {'; '.join(rec['problems'])} |"
    if g.get("rc") != 0:
        status = f"ghosts exit {g.get('rc')}: " + (g.get("refused") or "").split(": ", 1)[-1][:90]
        return f"| {label} | {rec.get('optical_surfaces', '?')} | {status} | | {g.get('seconds', 0):.0f} | " \
               f"{'; '.join(rec['problems'])} |"
    nom = g.get("nominal_w")
    nom_s = f"{nom:.3g}" if isinstance(nom, (int, float)) else str(nom)
    f = rec.get("focus") or {}
    focus_s = (f"; on axis {f['inside']:.2f} at the sequential focus" if "inside" in f
               else f"; sequential check: {f['error']}" if "error" in f else "")
    rad = g.get("nominal_radius_mm")
    rad_s = f", RMS {rad:.2g} mm" if isinstance(rad, (int, float)) else ""
    warns = len(g.get("warnings", []))
    return (f"| {label} | {rec.get('optical_surfaces', '?')} | ok | {g.get('count')} ({g.get('untraced', 0)} untraced, "
            f"{g.get('no_ray', 0)} no ray), nominal {nom_s} W{rad_s}{focus_s}, {warns} warnings | {g.get('seconds', 0):.0f} | "
            f"{'; '.join(rec['problems'])} |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--odb", type=Path, required=True, help="OpticsDatabase checkout (or its Optics folder)")
    ap.add_argument("--seq-dir", nargs="*", default=None,
                    help="folders of CODE V .seq files (default: rayoptics' codev/tests and tests/data/lenses)")
    ap.add_argument("--count", type=int, default=40)
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--max-seconds", type=float, default=20.0)
    ap.add_argument("--timeout", type=float, default=600.0, help="seconds before a command is killed")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--work", type=Path, default=Path("/tmp/ghost_sweep"))
    ap.add_argument("--focus", action="store_true",
                    help="also run tests/test_optics_focus.py's on-axis check on each imported file")
    ap.add_argument("--no-write", action="store_true", help="print only; leave benchmarks/RESULTS.md alone")
    args = ap.parse_args(argv)
    if args.seq_dir is None:
        import rayoptics

        args.seq_dir = [str(Path(rayoptics.__file__).parent / "codev" / "tests"), str(ROOT / "tests" / "data" / "lenses")]
    odb = args.odb / "Optics" if (args.odb / "Optics").is_dir() else args.odb
    zmx = pick_zemax(odb, args.count, args.seed)
    seqs = seq_files(args.seq_dir)
    lenses = [(p, f"odb:{p.relative_to(odb).as_posix()}") for p, _ in zmx] + \
             [(p, f"seq:{p.parent.name}/{p.name}") for p in seqs]
    args.work.mkdir(parents=True, exist_ok=True)
    (args.work / "files.txt").write_text("".join(f"{p}\n" for p, _ in lenses), encoding="utf-8")
    results = args.work / "results.jsonl"
    done = {}
    if results.exists():
        for line in results.read_text(encoding="utf-8").splitlines():
            r = json.loads(line)
            done[r["file"]] = r
    todo = [(k, p) for k, (p, _) in enumerate(lenses) if str(p) not in done]
    print(f"{len(lenses)} lenses ({len(zmx)} Zemax, {len(seqs)} CODE V), {len(todo)} to run", flush=True)
    with concurrent.futures.ThreadPoolExecutor(max(1, args.jobs)) as pool:
        futs = {pool.submit(sweep_one, p, args.work / f"{k:03d}", args.max_seconds, args.timeout, args.focus): p
                for k, p in todo}
        for f in concurrent.futures.as_completed(futs):
            rec = f.result()
            done[rec["file"]] = rec
            if rec.get("ghosts", {}).get("rc") == 0:
                check_tables(rec, Path(rec["work"]) / "ghosts")
                rec["problems"] += rec.pop("table_problems")
            with results.open("a", encoding="utf-8") as fh:
                fh.write(json.dumps(rec) + "\n")
            print(_row(rec, Path(rec["file"]).name), flush=True)
    recs = [done[str(p)] for p, _ in lenses]
    for k, r in enumerate(recs):
        r["problems"] = [x for x in r["problems"] if not x.startswith(("nulls", "nominal image power", "ghosts.json",
                                                                           "ghosts: missing"))]
        if r.get("ghosts", {}).get("rc") == 0:
            check_tables(r, args.work / f"{k:03d}" / "ghosts")
            r["problems"] += r["table_problems"]
    n_imp = sum(r["import"]["rc"] == 0 for r in recs)
    n_gh = sum(r.get("ghosts", {}).get("rc") == 0 for r in recs)
    times = sorted(r["ghosts"]["seconds"] for r in recs if r.get("ghosts", {}).get("rc") == 0)
    body = [f"{len(lenses)} lenses: {len(zmx)} Zemax files of OpticsDatabase (seed {args.seed}; list in "
            f"WORK/files.txt), {len(seqs)} CODE V files (rayoptics' codev/tests, tests/data/lenses). "
            f"`optics import` then `ghosts --max-seconds {args.max_seconds:g}` (defaults otherwise), "
            f"{args.jobs} at a time on a shared 2-core machine; seconds are the ghosts command's wall time"
            + ("; on axis: tests/test_optics_focus.py's check (power within 1.2 x the sequential spot)" if args.focus
               else "") + ".", "",
            f"Imported {n_imp}, refused {len(recs) - n_imp} (one line each); ghost tables {n_gh}; "
            f"problems on {sum(bool(r['problems']) for r in recs)} files."
            + (f" Ghosts command wall time median {times[len(times) // 2]:.0f} s, max {times[-1]:.0f} s." if times else "")]
    groups = [_group(label, info) for label, info in
              [(label, i) for (_, label), (_, i) in zip(lenses, zmx)] + [(label, None) for _, label in lenses[len(zmx):]]]
    summary = ["", "| group | files | imported | refused | ghost tables | ghosts cmd refused | median / max s | "
               "off the sequential focus | other problems |", "|---|---|---|---|---|---|---|---|---|"]
    for name in dict.fromkeys(groups):
        rs = [r for r, gname in zip(recs, groups) if gname == name]
        ok = [r for r in rs if r.get("ghosts", {}).get("rc") == 0]
        ts = sorted(r["ghosts"]["seconds"] for r in ok)
        off = sum(any(x.startswith("nominal image off") for x in r["problems"]) for r in rs)
        other = sum(any(not x.startswith("nominal image off") for x in r["problems"]) for r in rs)
        summary.append(f"| {name} | {len(rs)} | {sum(r['import']['rc'] == 0 for r in rs)} | "
                       f"{sum(r['import']['rc'] != 0 for r in rs)} | {len(ok)} | "
                       f"{sum(r.get('ghosts', {}).get('rc') not in (None, 0) for r in rs)} | "
                       + (f"{ts[len(ts) // 2]:.0f} / {ts[-1]:.0f}" if ts else "-") + f" | {off} | {other} |")
    body[3:3] = summary
    body += ["", "Per file:", "", "| lens | optical surfaces | result | ghosts | s | problems |", "|---|---|---|---|---|---|"]
    body += [_row(r, label) for r, (_, label) in zip(recs, lenses)]
    from results_md import publish

    publish("ghost_sweep", "\n".join(body), write=not args.no_write)
    return 0


if __name__ == "__main__":
    sys.exit(main())
