"""Thermal self-emission benchmark (shared BENCHMARK.md "Thermal"): the reference baffled
tube (BENCHMARK.md geometry, Lambertian 5 % walls) at 300 K, its detector at 77 K, band 8-12 um.

Prints, measured in one run on the same cores:
- time to 1 % relative standard error on the detector, reverse (default) vs forward estimator,
  each from a cold estimator (tables, embree scene and all), and their ratio;
- the two answers (they must agree within their errors);
- the whole ``straylight thermal --target-rel-error 0.01`` command on the tube's scene file;
- the Planck band integral against a fine Gauss-Legendre quadrature of Planck's law.

    python benchmarks/thermal.py [--target 0.01] [--seed 1] [--skip-cli]
"""
from __future__ import annotations

import argparse
import dataclasses
import itertools
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def tube_scene(wall_k=300.0, detector_k=77.0, rd=0.05):
    """(geometry.Scene with temperatures, materials) of the BENCHMARK.md tube."""
    from materials import load_material
    from straylight.analyses.builtin import tube_setup

    setup = tube_setup(material=load_material({"components": [{"type": "lambertian", "rd": rd}]}, name="black"))
    parts = tuple(dataclasses.replace(p, meta=dict(p.meta, temperature_k=detector_k if p.role == "detector" else wall_k))
                  for p in setup.scene.parts)
    return dataclasses.replace(setup.scene, parts=parts), setup.materials


def time_to_target(method, target, seed):
    """Seconds from the meshed scene to the target (embree scene, emissivity tables and tracing)."""
    from straylight.thermal.model import thermal_scene
    from straylight.thermal.run import thermal

    scene, mats = tube_scene()  # CadQuery + tessellation: cached after the first call, not timed
    t0, c0 = time.perf_counter(), time.process_time()
    res = thermal(thermal_scene(scene, mats), (8, 12), target_rel_error=target, seed=seed, method=method)
    return time.perf_counter() - t0, time.process_time() - c0, res.detectors["detector"]


def planck_check():
    from straylight.thermal.planck import (
        band_radiance_w_m2_sr,
        spectral_radiance_w_m2_sr_um,
    )

    rows = []
    for lo, hi, t in [(8, 12, 300.0), (3, 5, 300.0), (8, 12, 77.0), (0.1, 1000, 300.0)]:
        x, w = np.polynomial.legendre.leggauss(200)
        edges = np.geomspace(lo, hi, 401)
        q = 0.0
        for a, b in itertools.pairwise(edges):
            lam = 0.5 * (b - a) * x + 0.5 * (a + b)
            q += 0.5 * (b - a) * float(w @ spectral_radiance_w_m2_sr_um(lam, t))
        rows.append((lo, hi, t, band_radiance_w_m2_sr(lo, hi, t), q))
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--target", type=float, default=0.01)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--skip-cli", action="store_true")
    args = ap.parse_args(argv)
    print("Planck band radiance vs 400 x 200-point Gauss-Legendre quadrature (W m^-2 sr^-1):")
    for lo, hi, t, a, q in planck_check():
        print(f"  {lo:g}-{hi:g} um, {t:g} K: series {a:.12g}  quadrature {q:.12g}  rel. diff {a / q - 1:+.1e}")
    tube_scene()  # mesh the tube once (CadQuery), outside the timings
    time_to_target("reverse", 0.2, 0)  # and load numba and compile the materials' loops once (both need them)
    out = {}
    for method in ("reverse", "forward"):
        dt, cpu, d = time_to_target(method, args.target, args.seed)
        out[method] = (dt, cpu, d)
        print(f"{method:8s}: {d.power_w:.6e} +- {d.stderr_w:.2e} W ({d.stderr_w / d.power_w:.2%}) "
              f"in {dt:.2f} s wall, {cpu:.2f} s CPU, {d.rays} rays")
    (tr, cr, r), (tf, cf, f) = out["reverse"], out["forward"]
    z = (r.power_w - f.power_w) / np.hypot(r.stderr_w, f.stderr_w)
    print(f"time to {args.target:.0%}: forward / reverse = {tf / tr:.1f}x wall, {cf / cr:.1f}x CPU; "
          f"answers differ by {z:+.2f} sigma")
    # a run stops at the first round below the target, so compare CPU x relative variance too (the
    # time each would need for exactly the target if the error falls as 1/sqrt(N))
    er, ef = (r.stderr_w / r.power_w) ** 2 * cr, (f.stderr_w / f.power_w) ** 2 * cf
    print(f"CPU x rel. variance: reverse {er:.3g}, forward {ef:.3g}: forward / reverse = {ef / er:.0f}x")
    if not args.skip_cli:
        from geometry.io import save_scene
        from straylight.analyses.scene_setup import add_scene_tables

        scene, mats = tube_scene()
        with tempfile.TemporaryDirectory() as tmp:
            path = save_scene(scene, tmp)
            add_scene_tables(path, {"material": {"black": {k: v for k, v in mats["coating"].to_dict().items() if k != "name"}}})
            _temperatures(path, scene)
            exe = [sys.executable, "-m", "straylight.cli.main", "thermal", str(path), "--band-um", "8", "12",
                   "--target-rel-error", str(args.target), "--seed", str(args.seed), "--out", str(Path(tmp) / "o")]
            t0 = time.perf_counter()
            r0 = os.times()
            subprocess.run(exe, check=True, env=dict(os.environ), stdout=subprocess.DEVNULL)
            r1 = os.times()
            cpu = (r1.children_user - r0.children_user) + (r1.children_system - r0.children_system)
            print(f"whole command (straylight thermal --target-rel-error {args.target}, imports and scene "
                  f"loading included): {time.perf_counter() - t0:.2f} s wall, {cpu:.2f} s CPU")


def _temperatures(path, scene):
    """Write each part's temperature_k into the saved scene file."""
    import tomllib

    import tomli_w

    import atomicio

    doc = tomllib.loads(Path(path).read_text())
    temps = {p.name: p.meta["temperature_k"] for p in scene.parts}
    for entry in doc["part"]:
        entry["temperature_k"] = temps[entry["name"]]
        if entry.get("role", "surface") == "surface":
            entry["material"] = "black"
    doc.pop("source", None)
    atomicio.write_text(path, tomli_w.dumps(doc))


if __name__ == "__main__":
    main()
