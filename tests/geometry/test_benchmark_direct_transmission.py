"""The reference tube's direct (unscattered) transmission against BENCHMARK.md's hand formula.

direct(a) = [2 * 35^2 * acos(s / 70) - (s / 2) sqrt(70^2 - s^2)] / (pi 50^2), s = 280.5 tan a,
the lens where the top vane's hole (r = 35, top face z = 280.5) and the detector (r = 35, z = 0)
overlap as seen along the beam. Rays start uniformly over the entrance disk r < 50 at z = 300,
and the first surface each one meets (embreex) must be the detector for exactly that fraction.
This checks the geometry (positions, radii, normals' irrelevance, no gaps between parts), not
the tracer.
"""
import numpy as np
import pytest

from geometry.scenes import reference_scene

BENCHMARK_DIRECT = {0.0: 0.49000, 5.0: 0.27584, 10.0: 0.08927, 20.0: 0.0}


def direct(a_deg):
    s = 280.5 * np.tan(np.deg2rad(a_deg))
    if s >= 70:
        return 0.0
    return (2 * 35**2 * np.arccos(s / 70) - s / 2 * np.sqrt(70**2 - s**2)) / (np.pi * 50**2)


def first_hit_parts(scene, origins, dirs):
    import embreex.mesh_construction as mc
    import embreex.rtcore_scene as rtcs

    emb = rtcs.EmbreeScene()
    mc.TriangleMesh(emb, scene.triangles_mm.astype(np.float32))
    prim = emb.run(origins.astype(np.float32), dirs.astype(np.float32))
    return np.where(prim >= 0, scene.triangle_part[np.maximum(prim, 0)], -1)


@pytest.mark.parametrize("a_deg", sorted(BENCHMARK_DIRECT))
def test_direct_fraction_matches_benchmark_formula(a_deg):
    assert direct(a_deg) == pytest.approx(BENCHMARK_DIRECT[a_deg], abs=5e-6)  # the formula is BENCHMARK's
    scene = reference_scene(tolerance_mm=0.05)
    n = 1_000_000
    rng = np.random.default_rng(12345)
    r = 50.0 * np.sqrt(rng.random(n))
    phi = 2 * np.pi * rng.random(n)
    origins = np.stack([r * np.cos(phi), r * np.sin(phi), np.full(n, 300.0)], axis=1)
    a = np.deg2rad(a_deg)
    dirs = np.tile([np.sin(a), 0.0, -np.cos(a)], (n, 1))
    part = first_hit_parts(scene, origins, dirs)
    assert np.all(part >= 0)  # nothing leaves a closed tube through the bottom or the wall
    detector = scene.part_names.index("detector")
    p_hat = np.mean(part == detector)
    expected = direct(a_deg)
    # binomial standard error of the run, 4 sigma; plus the polygon bias: the inscribed N-gon hole
    # (N nodes on the r = 35 circle) has area deficit 1 - sin(2 pi/N)/(2 pi/N) ~ (2 pi/N)^2 / 6,
    # at most twice that on the lens (two polygonal circles)
    sigma = np.sqrt(max(expected * (1 - expected), 1e-12) / n)
    det = scene.part("detector").vertices_mm
    n_poly = len(det)
    bias = 2 * (2 * np.pi / n_poly) ** 2 / 6 * expected
    if expected > 0:
        assert p_hat > 0  # sanity: the geometry couples
    print(f"a = {a_deg} deg: direct {p_hat:.5f} vs {expected:.5f} (sigma {sigma:.1e}, polygon bias <= {bias:.1e})")
    assert abs(p_hat - expected) <= 4 * sigma + bias, (p_hat, expected, sigma, bias)
