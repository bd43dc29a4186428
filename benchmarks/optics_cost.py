"""Cost of the optical_surface interaction on the built-in Cassegrain, in one run.

    python benchmarks/optics_cost.py [--rays N] [--angle-deg A] [--repeats R]

Traces the telescope (mirrors: Fresnel aluminium, nothing else) three ways, interleaved, best of
R, CPU seconds per ray and per ray segment (cast), and prints each against "mirror role":

  mirror role    primary/secondary as role "mirror" (delta_reflection: facet normals, no refinement,
                 no polarization, constant R = the Fresnel R at normal incidence)
  no refinement  optical_surface with the analytic surfaces removed (facet normals); Fresnel s/p and
                 Stokes vectors on
  full           optical_surface with refinement onto the exact conics (the default)

The focal-plane power shows what the facet normals of a 0.02 mm mesh do to the image (it falls
off the 8 mm detector). NEE off (nothing scatters on the mirrors).
"""
import argparse
import math
import time
from dataclasses import replace

import numpy as np

from geometry import Scene
from geometry.mesh import Part
from geometry.parts.cassegrain import CassegrainParams, cassegrain_scene
from materials import load_material
from straylight.analyses.types import Beam
from straylight.trace import EstimatorOptions, PhysicsOptions, TraceOptions, trace


def variants():
    p = CassegrainParams()
    base = cassegrain_scene(p, tolerance_mm=0.02)
    mats = {"aluminium_mirror": load_material({"name": "al", "components": [{"type": "specular", "n": [0.96, 6.69]}]}),
            "z302_sample_b": load_material("z302_sample_b")}

    def rebuild(fn):
        return Scene(tuple(fn(q) for q in base.parts))

    mirror_role = rebuild(lambda q: Part(q.name, q.vertices_mm, q.faces, None, "mirror", q.meta)
                          if q.name in ("primary", "secondary") else q)
    no_refine = rebuild(lambda q: replace(q, surface=None) if q.name in ("primary", "secondary") else q)
    return {"mirror role": mirror_role, "no refinement": no_refine, "full": base}, mats, p


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rays", type=int, default=200_000)
    ap.add_argument("--angle-deg", type=float, default=0.0)
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args(argv)
    scenes, mats, p = variants()
    beam = Beam(center_mm=(0, 0, p.tube_front_mm + 10), axis=(0, 0, -1), radius_mm=p.tube_radius_mm + 1,
                pivot_mm=(0, 0, p.tube_front_mm))
    src = beam.source(math.radians(a.angle_deg))
    opts = TraceOptions(estimator=EstimatorOptions(nee=False), physics=PhysicsOptions(mirror_reflectance=float(
        mats["aluminium_mirror"].smooth_coefficients(np.array([1.0])).reflectance("u")[0])))
    best = {k: math.inf for k in scenes}
    det = {}
    segs = {}
    for name, sc in scenes.items():  # warm-up: compile kernels
        trace(sc, [src], 2000, seed=0, materials=mats, options=opts)
    for _ in range(a.repeats):
        for name, sc in scenes.items():
            t0 = time.process_time()
            res = trace(sc, [src], a.rays, seed=1, materials=mats, options=opts)
            best[name] = min(best[name], time.process_time() - t0)
            det[name] = res.detectors["focal_plane"]
            segs[name] = res.segments
    ref = best["mirror role"]
    print(f"Cassegrain at {a.angle_deg:g} deg, {a.rays} rays, best of {a.repeats} (CPU s; shared machine):")
    for name in scenes:
        per_seg = best[name] / segs[name]
        print(f"  {name:14s} {best[name]:7.3f} s  {1e6 * best[name] / a.rays:6.2f} us/ray  x{best[name] / ref:5.2f}   "
              f"{1e6 * per_seg:5.2f} us/segment x{per_seg / (ref / segs['mirror role']):5.2f}   "
              f"focal plane {det[name].power_w:.5f} +- {det[name].stderr_w:.1e} W")


if __name__ == "__main__":
    main()
