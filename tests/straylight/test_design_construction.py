"""The vane construction (straylight.design.construction) checked by brute force in 3-D.

The closed-form lit / seen intervals are not used by the checks here: rays are sampled in 3-D
(detector points over the whole disk, beam azimuths, a fine grid of off-axis angles) and tested
against every vane corner directly. The construction must show no vignetting within the field
and no wall point both lit at >= E and seen; an evenly spaced layout with too few vanes must show
both (so the checks can fail), and there the closed-form intervals must match the brute force.
"""
import math

import numpy as np
import pytest

from straylight.design.construction import (BaffleSpec, DesignError, analyse_layout, construct_vanes,
                                            evenly_spaced, layout_at)


def _corners(layout):
    spec = layout.spec
    return np.array([c for v in layout.vanes for c in spec.corners(v)])  # (n, 2): z, r


def field_rays_vignetted(layout, n=20_000, seed=0):
    """Fraction of field rays (detector disk -> entrance, off-axis <= F, half of them at exactly F)
    that touch a vane or miss the entrance: a 3-D check, independent of the envelope formula."""
    spec = layout.spec
    rng = np.random.default_rng(seed)
    rho = spec.stop_radius_mm * np.sqrt(rng.random(n))
    rho[: n // 4] = spec.stop_radius_mm  # the disk's edge: the most exposed points
    psi = 2 * np.pi * rng.random(n)
    p = np.stack([rho * np.cos(psi), rho * np.sin(psi)], axis=1)
    theta = np.radians(spec.field_deg) * np.sqrt(rng.random(n))
    theta[: n // 2] = np.radians(spec.field_deg)
    phi = 2 * np.pi * rng.random(n)
    phi[: n // 8] = psi[: n // 8]  # outward along the edge point's radius: the worst case
    slope = np.tan(theta)[:, None] * np.stack([np.cos(phi), np.sin(phi)], axis=1)
    corners = _corners(layout)
    heights = np.concatenate([corners[:, 0], [spec.tube_length_mm]])
    limits = np.concatenate([corners[:, 1], [spec.tube_radius_mm]])
    radius = np.linalg.norm(p[:, None, :] + heights[None, :, None] * slope[:, None, :], axis=2)
    return float(np.mean(np.any(radius > limits * (1 + 1e-12), axis=1)))


def lit_and_seen_points(layout, n_z=1500, seed=1):
    """Wall heights (3-D, wall point (R, 0, z)) both lit by a beam at >= E (grid of angles and
    azimuths) and seen from some detector point (grid over the disk); plus the lit and seen masks."""
    spec = layout.spec
    R, L, S = spec.tube_radius_mm, spec.tube_length_mm, spec.stop_radius_mm
    corners = _corners(layout)
    rng = np.random.default_rng(seed)
    z = np.sort(rng.uniform(0, L, n_z))
    inside_vane = np.zeros(n_z, bool)
    for v in layout.vanes:
        inside_vane |= np.abs(z - v.z_mm) <= v.thickness_mm / 2
    z = z[~inside_vane]
    # lit: the ray back from the wall point toward the beam passes every corner above and the entrance
    theta = np.radians(np.linspace(spec.exclusion_deg, 89.5, 160))
    phi = np.radians(np.linspace(-60, 60, 7))
    tt, pp = np.meshgrid(np.tan(theta), phi, indexing="ij")
    back = -np.stack([tt.ravel() * np.cos(pp.ravel()), tt.ravel() * np.sin(pp.ravel())], axis=1)  # per unit height
    heights = np.concatenate([corners[:, 0], [L]])
    limits = np.concatenate([corners[:, 1], [R]])
    lit = np.zeros(len(z), bool)
    for i, zw in enumerate(z):
        above = heights > zw
        dz = heights[above] - zw
        x = R + dz[None, :] * back[:, :1]
        y = dz[None, :] * back[:, 1:2]
        ok = np.all(np.hypot(x, y) < limits[above][None, :], axis=1)
        lit[i] = ok.any()
    # seen: a detector point whose line to the wall point passes every corner below
    rho, psi = np.meshgrid(S * np.linspace(0, 1, 15), np.radians(np.linspace(0, 360, 37)[:-1]), indexing="ij")
    det = np.stack([(rho * np.cos(psi)).ravel(), (rho * np.sin(psi)).ravel()], axis=1)
    seen = np.zeros(len(z), bool)
    for i, zw in enumerate(z):
        below = corners[:, 0] < zw
        s = corners[below, 0] / zw
        pts_x = det[:, :1] * (1 - s)[None, :] + R * s[None, :]
        pts_y = det[:, 1:] * (1 - s)[None, :]
        seen[i] = np.any(np.all(np.hypot(pts_x, pts_y) < corners[below, 1][None, :], axis=1))
    return z, lit, seen


CASES = [
    dict(tube_radius_mm=50, tube_length_mm=300, stop_radius_mm=35, field_deg=0, exclusion_deg=20),
    dict(tube_radius_mm=50, tube_length_mm=300, stop_radius_mm=30, field_deg=1.5, exclusion_deg=25,
         vane_thickness_mm=2.0, bevel_deg=30),
    dict(tube_radius_mm=40, tube_length_mm=400, stop_radius_mm=20, field_deg=2.0, exclusion_deg=15,
         vane_thickness_mm=0.5, bevel_deg=45, bevel_side="front"),
]


@pytest.mark.parametrize("case", CASES)
def test_construction_no_vignetting_and_nothing_lit_and_seen(case):
    layout = construct_vanes(**case)
    assert layout.complete and not layout.notes
    assert len(layout.vanes) >= 2
    z = [v.z_mm for v in layout.vanes]
    assert z == sorted(z)
    assert field_rays_vignetted(layout) == 0.0
    zw, lit, seen = lit_and_seen_points(layout)
    assert lit.any() and seen.any()  # the check has something to look at
    assert not np.any(lit & seen), f"lit and seen at z = {zw[lit & seen][:5]}"


def test_checks_can_fail_vignetting_and_lit_seen():
    """Vanes 0.05 mm inside the envelope vignette; 3 evenly spaced vanes leave wall lit and seen,
    and the closed-form intervals of analyse_layout match the brute force there."""
    layout = construct_vanes(**CASES[0])
    tighter = analyse_layout(layout.spec, [type(v)(v.z_mm, v.inner_radius_mm - 0.05, v.thickness_mm)
                                           for v in layout.vanes])
    assert tighter.vignetting_margin_mm < 0
    assert field_rays_vignetted(tighter) > 0
    sparse = evenly_spaced(layout.spec, 3)
    assert not sparse.complete and sparse.lit_and_seen_mm > 10
    zw, lit, seen = lit_and_seen_points(sparse, n_z=3000)
    both = zw[lit & seen]
    assert len(both) > 50
    intervals = [b.lit_and_seen_mm for b in sparse.bays if b.lit_and_seen_mm]
    # every brute-force point lies in a closed-form interval (0.5 mm: the angle grid's resolution) ...
    assert all(any(lo - 0.5 <= z <= hi + 0.5 for lo, hi in intervals) for z in both)
    # ... and the intervals are covered by brute-force points up to that resolution
    for lo, hi in intervals:
        inside = both[(both >= lo - 0.5) & (both <= hi + 0.5)]
        assert inside.min() - lo < 1.0 and hi - inside.max() < 1.0


def test_reference_tube_numbers_by_hand():
    """R 50, L 300, S 35, F 0, E 20, zero thickness: the top vane hides the wall above it when
    z (R + S) / (r + S) = L, z = 300 * 70 / 85 = 247.06 mm; the next bay is lit up to
    z_1 - (R - r) / tan(theta*), tan(theta*) = (R + r) / (L - z_1) (entrance and vane 1 edges)."""
    layout = construct_vanes(50, 300, 35, 0, 20, vane_thickness_mm=1e-9)
    z1 = 300 * 70 / 85
    assert layout.vanes[-1].z_mm == pytest.approx(z1, abs=1e-6)
    tan_star = 85 / (300 - z1)
    hi = z1 - 15 / tan_star
    assert layout.vanes[-2].z_mm == pytest.approx(hi * 70 / 85, abs=1e-6)
    assert len(layout.vanes) == 5  # light at 20 deg cannot pass vane 5 (hand count in docs/design.md)


def test_max_vanes_and_keep_out_are_reported():
    layout = construct_vanes(**CASES[0], max_vanes=2)
    assert len(layout.vanes) == 2 and not layout.complete and "max_vanes" in layout.notes[0]
    full = construct_vanes(**CASES[0])
    z2 = full.vanes[-2].z_mm
    kept = construct_vanes(**CASES[0], keep_out_mm=[(z2 - 5, z2 + 5)])
    assert all(not (z2 - 5 - 0.5 < v.z_mm < z2 + 5 + 0.5) for v in kept.vanes)
    assert kept.complete  # moved up, toward the entrance: still hides what it must
    zw, lit, seen = lit_and_seen_points(kept)
    assert not np.any(lit & seen)


@pytest.mark.parametrize("kwargs, message", [
    (dict(stop_radius_mm=50), "stop_radius_mm (50) must be below tube_radius_mm (50)"),
    (dict(stop_radius_mm=60), "stop_radius_mm (60) must be below"),
    (dict(field_deg=20), "field_deg (20) must be below exclusion_deg (20)"),
    (dict(field_deg=5), "too wide for the tube"),
    (dict(tube_radius_mm=-1), "tube_radius_mm must be a finite number > 0"),
    (dict(exclusion_deg=95), "exclusion_deg must be in (0, 90)"),
    (dict(vane_thickness_mm=0), "vane_thickness_mm must be"),
    (dict(bevel_deg=90), "bevel_deg must be in [0, 90)"),
    (dict(max_vanes=0), "max_vanes must be an integer >= 1"),
    (dict(keep_out_mm=[(100, 50)]), "keep-out zone (100, 50)"),
])
def test_bad_inputs_one_line(kwargs, message):
    with pytest.raises(DesignError) as err:
        construct_vanes(**{**CASES[0], **kwargs})
    assert message in str(err.value) and "\n" not in str(err.value)


def test_layout_at_and_spec_envelope():
    spec = BaffleSpec(50, 300, 30, 2.0, 20, vane_thickness_mm=2.0)
    lay = layout_at(spec, [100.0, 200.0])
    # square edge: the top corner binds; r = S + (z + t/2) tan F
    assert lay.vanes[0].inner_radius_mm == pytest.approx(30 + 101 * math.tan(math.radians(2)))
    assert lay.vignetting_margin_mm == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(DesignError, match="overlap"):
        layout_at(spec, [100.0, 100.5])
