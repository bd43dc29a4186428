"""The compiled scatter azimuth and real-index Rayleigh-Rice factor (materials.fresnel) give the same
bits as their vectorised numpy formulations below (Germer 1997 / PHYSICS §1 as numpy evaluates it),
edge cases included: normal incidence, theta_r = 0, grazing, NaN, eps = 1 (0/0)."""
import numpy as np
import pytest

from materials.fresnel import polarization_factor, scatter_azimuth


def _azimuth_numpy(wi, wo):
    tx, ty = -wi[:, 0], -wi[:, 1]
    ox, oy = wo[:, 0], wo[:, 1]
    norm = np.hypot(tx, ty) * np.hypot(ox, oy)
    ok = norm > 1e-30
    inv = 1.0 / np.where(ok, norm, 1.0)
    cos_phi = (ox * tx + oy * ty) * inv
    sin_phi = (tx * oy - ty * ox) * inv
    bad = ~ok
    on = np.hypot(ox, oy)
    normal = bad & (on > 1e-15)
    cos_phi[bad] = np.where(normal[bad], ox[bad] / np.where(normal[bad], on[bad], 1.0), 1.0)
    sin_phi[bad] = np.where(normal[bad], oy[bad] / np.where(normal[bad], on[bad], 1.0), 0.0)
    return cos_phi, sin_phi


def _q_numpy(cos_i, cos_r, cos_phi, sin_phi, eps, polarization):
    sin2_i = np.maximum(0.0, 1.0 - cos_i * cos_i)
    sin2_r = np.maximum(0.0, 1.0 - cos_r * cos_r)
    qi, qr = np.sqrt(eps - sin2_i), np.sqrt(eps - sin2_r)
    e1 = eps - 1.0
    di_s, di_p = cos_i + qi, eps * cos_i + qi
    dr_s, dr_p = cos_r + qr, eps * cos_r + qr
    ss = e1 * cos_phi / (di_s * dr_s)
    ps = e1 * qr * sin_phi / (di_s * dr_p)
    qs = np.square(ss) + np.square(ps)
    sp = e1 * qi * sin_phi / (di_p * dr_s)
    pp = e1 * (qi * qr * cos_phi - eps * np.sqrt(sin2_i * sin2_r)) / (di_p * dr_p)
    qp = np.square(pp) + np.square(sp)
    return {"s": qs, "p": qp, "u": 0.5 * qs + 0.5 * qp}[polarization]


def _directions(rng, n):
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def test_azimuth_is_numpys_to_the_bit():
    rng = np.random.default_rng(21)
    wi, wo = _directions(rng, 200_000), _directions(rng, 200_000)
    wi[:100] = [0.0, 0.0, 1.0]  # normal incidence
    wo[50:150] = [0.0, 0.0, 1.0]  # theta_r = 0 (and both)
    wi[200:210] = [1e-20, 0.0, 1.0]
    wo[300:305] = np.nan
    got, want = scatter_azimuth(wi, wo), _azimuth_numpy(wi, wo)
    for g, w in zip(got, want):
        np.testing.assert_array_equal(g, w)
    assert got[0][:50].tolist() == list(wo[:50, 0] / np.hypot(wo[:50, 0], wo[:50, 1]))  # plane xz
    assert (got[0][100:150] == 1.0).all() and (got[1][100:150] == 0.0).all()


@pytest.mark.parametrize("n", [1.0, 1.5, 2.3 + 0j])
@pytest.mark.parametrize("polarization", ["s", "p", "u"])
def test_real_index_factor_is_numpys_to_the_bit(n, polarization):
    rng = np.random.default_rng(22)
    wi, wo = _directions(rng, 100_000), _directions(rng, 100_000)
    cos_phi, sin_phi = _azimuth_numpy(wi, wo)
    ci, cr = np.abs(wi[:, 2]), np.abs(wo[:, 2])
    ci[:6] = [0.0, 1.0, np.nan, 0.5, 0.0, 1e-300]
    cr[:6] = [0.0, 1.0, 0.3, np.nan, 1.0, 0.0]
    with np.errstate(all="ignore"):
        want = _q_numpy(ci, cr, cos_phi, sin_phi, complex(n).real ** 2, polarization)
        got = polarization_factor(ci, cr, cos_phi, sin_phi, n, polarization)
    np.testing.assert_array_equal(got, want)
    # scalars broadcast as before
    assert polarization_factor(0.5, 0.7, 1.0, 0.0, n, polarization).shape == ()


@pytest.mark.parametrize("m", [1.5, 1 / 1.5, 1.0, complex(1.5, 0.01), complex(0.96, 6.69), 2.4],
                         ids=["glass", "glass-back", "index-matched", "absorbing", "aluminium", "high"])
def test_fresnel_amplitudes_are_numpys_to_the_bit(m):
    """The compiled amplitudes (scalar m) give the numpy formulation's bits, signed zeros included:
    random cosines, normal and grazing incidence, -0, tiny cosines, total internal reflection (m < 1)."""
    from materials.fresnel import fresnel_amplitudes, fresnel_amplitudes_numpy

    c = np.random.default_rng(3).random(100_000)
    c[:10], c[10:20], c[20], c[21:30] = 0.0, 1.0, -0.0, 1e-300
    with np.errstate(all="ignore"):
        got, want = fresnel_amplitudes(c, m), fresnel_amplitudes_numpy(c, m)
    for g, w in zip(got, want):
        np.testing.assert_array_equal(g, w)
        assert np.array_equal(np.signbit(g.real), np.signbit(w.real))
        assert np.array_equal(np.signbit(g.imag), np.signbit(w.imag))
    if np.imag(m) == 0 and np.real(m) < 1:
        assert (np.abs(got[0][c < 0.5]) > 1 - 1e-12).all()  # total internal reflection below the critical angle


def test_read_only_directions_run_the_same_compiled_loop():
    """Read-only inputs (numba types them apart from writable ones) are copied: one compiled azimuth loop."""
    from materials.fresnel import _scatter_azimuth_loop
    from materials.sampling import _COMPILED

    rng = np.random.default_rng(5)
    wi, wo = _directions(rng, 40), _directions(rng, 40)
    expected = scatter_azimuth(wi, wo)
    wi.flags.writeable = False
    got = scatter_azimuth(wi, wo)
    wo.flags.writeable = False
    got2 = scatter_azimuth(wi, wo)
    for e, g, g2 in zip(expected, got, got2):
        np.testing.assert_array_equal(e, g)
        np.testing.assert_array_equal(e, g2)
    assert len(_COMPILED[_scatter_azimuth_loop].signatures) == 1, _COMPILED[_scatter_azimuth_loop].signatures
