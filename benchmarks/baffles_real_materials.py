"""Telescope shields with real materials, confirmed by an independent trace of the exported STEP solids.

    .venv/bin/python benchmarks/baffles_real_materials.py [--telescopes cassegrain ritchey_chretien maksutov_cassegrain]
        [--target 0.03] [--angles-deg 2.8 5.2 7.6 10] [--out DIR] [--no-write]

For each telescope of examples/telescopes/ (classical Cassegrain, Ritchey-Chretien, Maksutov), `straylight design
baffles` designs the shields; then `straylight pst` (the scene's own materials: aluminium mirrors with 2 nm rms
roughness, z302 shields) traces

- before: `scene_unshielded.toml` (the bare telescope),
- after: `scene.toml` (the shields as exact analytic sheets),
- after, STEP: the same scene with the shields replaced by `baffles.step` read by the CAD loader (split into its
  named solids, meshed at 0.05 mm): an independent geometry path (OCCT solids with thickness and knife edges,
  triangle meshes) for the same design.

The table gives the three PSTs with their standard errors and z = (analytic - STEP) / sqrt(se_a^2 + se_s^2).
It is written to benchmarks/RESULTS.md, one section per telescope (``baffles_real_materials (NAME)``), so the
telescopes can be run separately (the Ritchey-Chretien and the Maksutov take longest).
"""
from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TELESCOPES = [("cassegrain.toml", 0.2), ("ritchey_chretien.toml", 0.1), ("maksutov_cassegrain.toml", 0.25)]


def _straylight(*args) -> None:
    exe = Path(sys.executable).with_name("straylight")
    subprocess.run([str(exe), *map(str, args)], check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def _pst(scene: Path, angles, target: float, out: Path) -> dict:
    _straylight("pst", scene, "--angles-deg", *angles, "--target-rel-error", target, "--seed", 7, "--out", out)
    rows = json.loads((out / "pst.json").read_text())["points"]
    return {round(float(r["off_axis_deg"]), 6): r for r in rows}


def _step_scene(out: Path) -> Path:
    import tomli_w

    doc = tomllib.loads((out / "scene.toml").read_text())
    doc["part"] = [p for p in doc["part"] if not p["name"].startswith("baffle_")]
    doc["part"].append({"name": "cad", "mesh": str((out / "baffles.step").resolve()), "split": "solids",
                        "material": "z302_sample_b", "tolerance_mm": 0.05})
    path = out / "step_scene.toml"
    path.write_text(tomli_w.dumps(doc))
    return path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--target", type=float, default=0.03)
    ap.add_argument("--angles-deg", type=float, nargs="+", default=[2.8, 5.2, 7.6, 10.0])
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--telescopes", nargs="+", default=[n.removesuffix(".toml") for n, _ in TELESCOPES],
                    choices=[n.removesuffix(".toml") for n, _ in TELESCOPES])
    ap.add_argument("--no-write", action="store_true", help="print only; leave benchmarks/RESULTS.md alone")
    a = ap.parse_args(argv)
    work = a.out or Path(tempfile.mkdtemp(prefix="baffles_real_"))
    for name, field in TELESCOPES:
        if name.removesuffix(".toml") in a.telescopes:
            _one_telescope(name, field, a, work)
    return 0


def _one_telescope(name: str, field: float, a, work: Path) -> None:
    lines = [f"Shields by `design baffles`, then `straylight pst --target-rel-error {a.target}` with the scenes' own "
             "materials (aluminium mirrors with 2 nm rms roughness, z302_sample_b shields); STEP: the shields replaced "
             "by the exported `baffles.step` solids (CAD loader, 0.05 mm mesh). z = (analytic - STEP) / combined "
             "standard error.", "",
             "| telescope | angle (deg) | PST before | PST after (analytic shields) | PST after (STEP solids) | z |",
             "|---|---|---|---|---|---|"]
    worst = 0.0
    out = work / name.removesuffix(".toml")
    _straylight("design", "baffles", ROOT / "examples" / "telescopes" / name, "--field-deg", field,
                "--rays", 6000, "--refine-rays", 2000, "--force", "--out", out)
    before = _pst(out / "scene_unshielded.toml", a.angles_deg, a.target, out / "pst_before")
    after = _pst(out / "scene.toml", a.angles_deg, a.target, out / "pst_after")
    step = _pst(_step_scene(out), a.angles_deg, a.target, out / "pst_step")
    for ang in a.angles_deg:
        b, r, s = (d[round(ang, 6)] for d in (before, after, step))
        se = math.hypot(r["pst_stderr"], s["pst_stderr"])
        z = (r["pst"] - s["pst"]) / se if se > 0 else 0.0
        worst = max(worst, abs(z))
        row = f"| {name.removesuffix('.toml')} | {ang:g} | " + " | ".join(
            f"{d['pst']:.3g} +- {d['pst_stderr']:.2g}" for d in (b, r, s)) + f" | {z:+.2f} |"
        lines.append(row)
        print(row, flush=True)
    lines += ["", f"Largest |z| between the analytic shields and the STEP solids: {worst:.2f}."]
    print(f"{name}: largest |z| analytic vs STEP: {worst:.2f}", flush=True)
    if not a.no_write:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from results_md import write_section

        write_section("baffles_real_materials", "\n".join(lines), name_suffix=name.removesuffix(".toml"))
        print("written benchmarks/RESULTS.md", flush=True)


if __name__ == "__main__":
    raise SystemExit(main())
