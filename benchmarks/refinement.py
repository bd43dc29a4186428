"""Cost of refining hits onto an analytic surface (geometry.analytic), per hit, against the embree
cast that found them, measured in the same run.

    python benchmarks/refinement.py [--rays N] [--tolerance-mm T]

Paraboloid R = 2000 mm, aperture 20..100 mm, meshed at T; a collimated on-axis beam; prints the
embree cast (intersect, with the float64 distance) and Newton refinement + exact normals, in
us per hit and as a ratio, best of 3. Also reports Newton iterations used.
"""
import argparse
import time

import numpy as np

from geometry.analytic import analytic_part, surface_from_dict
from straylight.intersect import EmbreeIntersector


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rays", type=int, default=400_000)
    ap.add_argument("--tolerance-mm", type=float, default=0.01)
    a = ap.parse_args(argv)
    surf = surface_from_dict({"type": "conic", "radius_mm": 2000.0, "conic": -1.0, "outer_radius_mm": 100.0,
                              "inner_radius_mm": 20.0})
    part = analytic_part("primary", surf, tolerance_mm=a.tolerance_mm)
    isect = EmbreeIntersector(part.vertices_mm[part.faces])
    rng = np.random.default_rng(1)
    r = np.sqrt(rng.uniform(21.0**2, 99.0**2, a.rays))
    phi = rng.uniform(0, 2 * np.pi, a.rays)
    o = np.column_stack([r * np.cos(phi), r * np.sin(phi), np.full(a.rays, 1500.0)])
    d = np.tile([0.0, 0.0, -1.0], (a.rays, 1)) + rng.normal(0, 1e-3, (a.rays, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    best_cast = best_ref = best_np = np.inf
    surf.refine_hits(o[:10], d[:10], np.full(10, 1500.0))  # compile (cached) outside the timing
    for _ in range(3):
        t0 = time.perf_counter()
        tri, t = isect.intersect(o, d)
        best_cast = min(best_cast, time.perf_counter() - t0)
        hit = tri >= 0
        oh, dh, th = o[hit], d[hit], t[hit]
        t0 = time.perf_counter()
        tr, n, ok = surf.refine_hits(oh, dh, th)
        best_ref = min(best_ref, time.perf_counter() - t0)
        t0 = time.perf_counter()
        tr2, ok2 = surf.refine(oh, dh, th)
        n2 = surf.normals(oh + tr2[:, None] * dh)
        best_np = min(best_np, time.perf_counter() - t0)
    hits = int(np.sum(tri >= 0))
    print(f"mesh: {part.n_triangles} triangles at {a.tolerance_mm} mm; {hits} hits of {a.rays} rays "
          f"(max |t - t_mesh| = {np.abs(tr - th).max():.2e} mm)")
    print(f"embree cast:           {1e6 * best_cast / a.rays:.3f} us/ray")
    print(f"refine + exact normal: {1e6 * best_ref / hits:.3f} us/hit  (x{best_ref / best_cast * a.rays / hits:.2f} "
          "the cast per ray; compiled kernel)")
    print(f"numpy reference:       {1e6 * best_np / hits:.3f} us/hit")
    assert np.all(ok) and np.all(ok2) and np.abs(tr - tr2).max() < 1e-9 and np.abs(n - n2).max() < 1e-12


if __name__ == "__main__":
    main()
