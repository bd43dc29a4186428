"""The built-in Cassegrain: an on-axis beam reflected by the exact primary and secondary (hits refined
onto the analytic surfaces) converges to the Cassegrain focus, unobstructed by baffles and vanes.

Reference: a classical Cassegrain (paraboloid + hyperboloid sharing the prime focus) images an
axial point without aberration (Schroeder, *Astronomical Optics*, 2nd ed., §6.2): every ray meets
the axis at z = -b, and the system focal length is m f1 (the marginal ray's slope is D/2 / F).
"""
import numpy as np

from geometry.parts.cassegrain import CassegrainParams, cassegrain_scene
from materials.smooth import reflect
from straylight.intersect import EmbreeIntersector


def _walk(scene, o, d, max_bounces=4):
    """Specular walk: mirrors (primary, secondary fronts) reflect with exact normals; anything else stops."""
    tri_part = scene.triangle_part
    isect = EmbreeIntersector(scene.triangles_mm)
    names = scene.part_names
    path = [[] for _ in range(len(o))]
    alive = np.ones(len(o), bool)
    last = np.full(len(o), -1)
    for _ in range(max_bounces):
        idx = np.flatnonzero(alive)
        tri, t = isect.intersect(o[idx], d[idx])
        # a ray leaving an exact surface can meet that surface's own mesh (a chord away): such a hit
        # refines back onto the ray's origin; cast again from just beyond the chord
        for _ in range(3):
            again = (tri >= 0) & (tri_part[np.maximum(tri, 0)] == last[idx])
            if not np.any(again):
                break
            rows = idx[again]
            surf = scene.parts[last[rows[0]]].surface if len(set(last[rows])) == 1 else None
            if surf is None:
                break
            tr, _, _ = surf.refine_hits(o[rows], d[rows], t[again])
            self_hit = np.abs(tr) < 1e-6
            if not np.any(self_hit):
                break
            sel = np.flatnonzero(again)[self_hit]
            skip = t[sel] + 1e-6
            tri2, t2 = isect.intersect(o[idx[sel]] + skip[:, None] * d[idx[sel]], d[idx[sel]])
            tri[sel], t[sel] = tri2, t2 + skip
        hit = tri >= 0
        alive[idx[~hit]] = False
        idx, tri, t = idx[hit], tri[hit], t[hit]
        part = tri_part[tri]
        last[idx] = part
        for k, j in enumerate(idx):
            path[j].append(names[part[k]])
        for pi in np.unique(part):
            sel = part == pi
            rows = idx[sel]
            surf = scene.parts[pi].surface
            tr, n, ok = surf.refine_hits(o[rows], d[rows], t[sel])
            o[rows] = o[rows] + tr[:, None] * d[rows]
            front = np.einsum("ij,ij->i", d[rows], n) < 0
            if names[pi] in ("primary", "secondary"):
                refl = ok & front
                d[rows[refl]] = reflect(d[rows[refl]], n[refl])
                alive[rows[~refl]] = False
            else:
                alive[rows] = False
    return o, d, path


def test_on_axis_beam_focuses_on_the_focal_plane():
    p = CassegrainParams()
    scene = cassegrain_scene(p, tolerance_mm=0.05)
    assert {"primary", "secondary", "secondary_baffle", "primary_baffle", "tube", "vane_1", "end_plate",
            "focal_plane"} <= set(scene.part_names)
    rng = np.random.default_rng(2)
    n = 4000
    r = np.sqrt(rng.uniform((p.secondary_radius_mm + 2.0) ** 2, (p.aperture_radius_mm - 0.5) ** 2, n))
    phi = rng.uniform(0, 2 * np.pi, n)
    o = np.column_stack([r * np.cos(phi), r * np.sin(phi), np.full(n, p.tube_front_mm + 5.0)])
    d = np.tile([0.0, 0.0, -1.0], (n, 1))
    o, d, path = _walk(scene, o.copy(), d.copy())
    assert all(pp == ["primary", "secondary", "focal_plane"] for pp in path), {tuple(pp) for pp in path}
    np.testing.assert_allclose(o[:, 2], -p.back_focus_mm, atol=1e-9)
    assert np.hypot(o[:, 0], o[:, 1]).max() < 1e-6  # a point image on the focal plane
    # system focal length: the ray at height h arrives with slope h / F
    slope = np.hypot(d[:, 0], d[:, 1]) / -d[:, 2]
    # paraxial: slope = r / F; the marginal rays of this fast (F/2) primary deviate by a few per cent
    np.testing.assert_allclose(slope, r / p.focal_length_mm, rtol=0.05)
