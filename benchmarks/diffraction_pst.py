"""PST of the reference tube near its cut-off with and without edge diffraction.

    .venv/bin/python benchmarks/diffraction_pst.py [--quick] [--rays N] [--angles-deg 10 12 ...]
        [--wavelengths-nm 500 10000] [--json OUT.json]

The BENCHMARK.md tube (Lambertian walls of reflectance 0.05, 7 vanes with 35 mm holes, geometric
cut-off 14.0 deg) with every edge of the wall, the vanes and the end plate marked
``diffraction = "edges"`` (CONTRACTS §6.5: their square 1 mm rims, 90 deg dihedrals), traced by
``pst_sweep`` at each wavelength with diffraction on (HURB, docs/diffraction.md) and off, same
rays and seed. Printed per angle: PST on and off with standard errors, their ratio, and the CPU
seconds of each point (one process, one core; the machine is shared, so compare the on/off times
of the same run). With diffraction on, first- and second-vertex sampling are off (they do not see
diffraction, straylight.engine.estimators); the off run keeps them, as ``straylight pst`` does, and
an off run without them is timed too, so the cost of diffraction itself is separated from the
estimators it turns off.
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np


def diffracting_tube(wavelength_nm: float):
    """The reference tube setup with every non-detector part diffracting, beam at ``wavelength_nm``."""
    from geometry.mesh import Part, Scene
    from materials import Lambertian
    from straylight.analyses.builtin import tube_setup

    setup = tube_setup(material=Lambertian(rd=0.05))
    parts = tuple(p if p.role == "detector" else
                  Part(p.name, p.vertices_mm, p.faces, p.material, p.role, {**p.meta, "diffraction": "edges"})
                  for p in setup.scene.parts)
    return replace(setup, scene=Scene(parts), beam=replace(setup.beam, wavelength_nm=float(wavelength_nm)))


def run_point(setup, angle_deg, rays, seed, options):
    from straylight.analyses.pst import pst_sweep

    c0 = time.process_time()
    res = pst_sweep(setup, np.radians([angle_deg]), n_rays=rays, seed=seed, options=options)
    cpu = time.process_time() - c0
    row = res.rows()[0]
    return {"pst": row["pst"], "pst_stderr": row["pst_stderr"], "cpu_s": cpu}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smoke run with few rays")
    parser.add_argument("--rays", type=int, default=None, help="rays per point (default 400000; quick 20000)")
    parser.add_argument("--angles-deg", type=float, nargs="+", default=[10.0, 12.0, 14.0, 16.0, 18.0, 20.0])
    parser.add_argument("--wavelengths-nm", type=float, nargs="+", default=[500.0, 10000.0])
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    from straylight.analyses.estimators import estimator_options
    from straylight.trace import PhysicsOptions, TraceOptions

    rays = args.rays or (20_000 if args.quick else 400_000)
    # what `straylight pst` traces
    on = estimator_options("default", TraceOptions(physics=PhysicsOptions(diffraction="scene")))
    off = replace(on, diffraction="off")
    off_plain = replace(off, first_vertex_sampling=False, second_vertex_sampling=False, vertex_lobe_sampling=False)
    rows = []
    print(f"reference tube (BENCHMARK.md), Lambertian 0.05, every edge diffracting (HURB); {rays} rays per point, "
          f"seed {args.seed}; CPU seconds per point, 1 core")
    print(f"{'lambda':>8} {'a (deg)':>7} {'PST off':>10} {'+-':>8} {'PST on':>10} {'+-':>8} {'on/off':>7} "
          f"{'cpu off':>8} {'cpu off*':>8} {'cpu on':>7}")
    for lam in args.wavelengths_nm:
        setup = diffracting_tube(lam)
        run_point(setup, args.angles_deg[0], 2000, args.seed, on)  # compile and cache before timing
        for a in args.angles_deg:
            r_off = run_point(setup, a, rays, args.seed, off)
            r_plain = run_point(setup, a, rays, args.seed, off_plain)
            r_on = run_point(setup, a, rays, args.seed, on)
            ratio = r_on["pst"] / r_off["pst"] if r_off["pst"] > 0 else float("nan")
            rows.append({"wavelength_nm": lam, "off_axis_deg": a, "rays": rays, "off": r_off, "off_plain": r_plain,
                         "on": r_on, "on_over_off": ratio})
            print(f"{lam:8.0f} {a:7.1f} {r_off['pst']:10.3e} {r_off['pst_stderr']:8.1e} {r_on['pst']:10.3e} "
                  f"{r_on['pst_stderr']:8.1e} {ratio:7.2f} {r_off['cpu_s']:8.1f} {r_plain['cpu_s']:8.1f} "
                  f"{r_on['cpu_s']:7.1f}")
    print("cpu off*: diffraction off without first/second-vertex sampling (the estimators a diffracting trace runs)")
    if args.json:
        args.json.write_text(json.dumps({"rows": rows}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
