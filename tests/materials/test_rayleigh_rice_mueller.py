"""The Rayleigh-Rice Jones/Mueller BRDF (materials.rayleigh_rice, materials.polarized_brdf).

Independent references:
- Germer, Appl. Opt. 36, 8798 (1997) / NIST SCATMECH amplitudes ss, ps, sp, pp as written in
  PHYSICS §1 (validated there against SCATMECH for |.|^2): the magnitudes |J| must equal theirs,
  for a dielectric, an absorbing substrate and a metal.
- At the specular direction the first-order amplitude is the Fresnel reflection (PHYSICS §1:
  Q_ss = R_s, Q_pp = R_p); with the vectors it must be diag(r_s, r_p) of the tracer's own s/p
  convention up to one common phase.
- Weak contrast (eps -> 1, Born / dipole layer, Jackson §10.1): the scattered field is the
  projection of the incident polarization onto the scattered one, so |det J| / scale^2 = |k_i . k_r|
  (the cosine between the two wave vectors): a check of the relative phases of the cross terms,
  which the magnitudes do not see. The signed amplitudes of PHYSICS §1 fail it out of plane (their
  relative signs are a magnitude-only transcription; shown below), which is why the tracer builds
  J from vectors.
- A sum of physical Mueller matrices has degree of polarization <= 1; unpolarized light sees the
  mean of the s and p BRDFs.
- The compiled per-ray pass (``rayleigh_rice_mueller``) against its numpy twin
  (``rayleigh_rice_jones`` + ``jones_to_mueller``): the same bits for a real index; for a complex one
  within 1e-13 (numpy's vectorised complex product fuses a multiply-add on FMA CPUs, the kernel
  does not).
"""
import numpy as np
import pytest

from materials import load_material
from materials.base import directions_from_angles
from materials.fresnel import fresnel_amplitudes, scatter_azimuth
from materials.mueller import interface_mueller, jones_to_mueller
from materials.polarized_brdf import is_polarizing, mueller_brdf
from materials.rayleigh_rice import rayleigh_rice_jones, rayleigh_rice_mueller, rayleigh_rice_mueller_numpy, s_basis

ANGLES = np.deg2rad(np.array([(10, 20, 5), (45, 30, 30), (45, 60, 90), (80, 70, 150), (30, 40, 180), (60, 10, 120),
                              (20, 75, 45)], float))
INDICES = [1.5, complex(1.6, 0.3), complex(0.96, 6.69)]


def _germer(ci, cr, cphi, sphi, n):
    eps = complex(n) ** 2
    si, sr = np.sqrt(1 - ci**2), np.sqrt(1 - cr**2)
    qi, qr = np.sqrt(eps - si**2 + 0j), np.sqrt(eps - sr**2 + 0j)
    ss = (eps - 1) * cphi / ((ci + qi) * (cr + qr))
    ps = (eps - 1) * qr * sphi / ((ci + qi) * (eps * cr + qr))
    sp = (eps - 1) * qi * sphi / ((eps * ci + qi) * (cr + qr))
    pp = (eps - 1) * (qi * qr * cphi - eps * si * sr) / ((eps * ci + qi) * (eps * cr + qr))
    return ss, ps, sp, pp


def _dirs(angles=ANGLES):
    return directions_from_angles(angles[:, 0], angles[:, 1], angles[:, 2])


@pytest.mark.parametrize("n", INDICES, ids=["glass", "absorbing", "aluminium"])
def test_jones_magnitudes_are_germers(n):
    wi, wo = _dirs()
    J, _ = rayleigh_rice_jones(wi, wo, n)
    ss, ps, sp, pp = _germer(wi[:, 2], wo[:, 2], *scatter_azimuth(wi, wo), n)
    # rows: scattered (s, p); columns: incident (s, p); ps = p out of s in
    for got, want in ((J[:, 0, 0], ss), (J[:, 1, 0], ps), (J[:, 0, 1], sp), (J[:, 1, 1], pp)):
        np.testing.assert_allclose(np.abs(got), np.abs(want), rtol=1e-10, atol=1e-14)


@pytest.mark.parametrize("n", INDICES, ids=["glass", "absorbing", "aluminium"])
def test_at_specular_the_jones_matrix_is_fresnel_in_the_tracers_basis(n):
    th = np.deg2rad(np.array([0.0, 20.0, 56.3, 75.0]))
    wi, wo = directions_from_angles(th, th, np.zeros(4))
    J, _ = rayleigh_rice_jones(wi, wo, n)
    rs, rp, *_ = fresnel_amplitudes(np.cos(th), complex(n))
    np.testing.assert_allclose(J[:, 0, 0], -rs, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(J[:, 1, 1], -rp, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(J[:, 0, 1], 0, atol=1e-14)
    np.testing.assert_allclose(J[:, 1, 0], 0, atol=1e-14)
    # so the Mueller matrix of specular scatter is the mirror's (materials.mueller.interface_mueller)
    np.testing.assert_allclose(jones_to_mueller(J), interface_mueller(rs, rp), atol=1e-13)


def test_weak_contrast_limit_projects_the_polarization():
    wi, wo = _dirs()
    delta = 1e-8
    n = np.sqrt(1 + delta)
    scale = delta / (4 * wi[:, 2] * wo[:, 2])
    J, _ = rayleigh_rice_jones(wi, wo, n)
    k_dot = np.einsum("ij,ij->i", -wi, wo)
    np.testing.assert_allclose(np.abs(np.linalg.det(J)) / scale**2, np.abs(k_dot), rtol=1e-5)
    ss, ps, sp, pp = _germer(wi[:, 2], wo[:, 2], *scatter_azimuth(wi, wo), n)
    signed = np.abs(ss * pp - sp * ps) / scale**2
    assert not np.allclose(signed, np.abs(k_dot), rtol=1e-3)  # the magnitude-only signs of PHYSICS §1


def test_jones_to_mueller_is_the_diagonal_formula_and_keeps_full_polarization():
    rng = np.random.default_rng(4)
    a = rng.normal(size=5) + 1j * rng.normal(size=5)
    b = rng.normal(size=5) + 1j * rng.normal(size=5)
    J = np.zeros((5, 2, 2), complex)
    J[:, 0, 0], J[:, 1, 1] = a, b
    np.testing.assert_allclose(jones_to_mueller(J), interface_mueller(a, b), atol=1e-12)
    # a general Jones matrix maps fully polarized light to fully polarized light (DOP = 1)
    J = rng.normal(size=(50, 2, 2)) + 1j * rng.normal(size=(50, 2, 2))
    E = rng.normal(size=(50, 2)) + 1j * rng.normal(size=(50, 2))
    Eo = np.einsum("nij,nj->ni", J, E)

    def stokes(e):
        return np.stack([abs(e[:, 0]) ** 2 + abs(e[:, 1]) ** 2, abs(e[:, 0]) ** 2 - abs(e[:, 1]) ** 2,
                         2 * (e[:, 0] * np.conj(e[:, 1])).real, 2 * (np.conj(e[:, 0]) * e[:, 1]).imag], axis=1)

    np.testing.assert_allclose(np.einsum("nij,nj->ni", jones_to_mueller(J), stokes(E)), stokes(Eo), rtol=1e-10,
                               atol=1e-10)


Z302B = load_material("z302_sample_b")
GLOSSY_PAINT = load_material({"name": "p", "wavelength_nm": 532.0, "components": [
    {"type": "lambertian", "rd": 0.05}, {"type": "k_correlation", "sigma_nm": 10.0, "lc_um": 2.0, "s": 2.6, "n": 1.5},
    {"type": "abg", "a": 0.01, "b": 0.001, "g": 2.0}]})


@pytest.mark.parametrize("model", [Z302B, GLOSSY_PAINT], ids=["z302b", "lambert+kcorr+abg"])
def test_material_mueller_first_row_is_the_s_and_p_brdf_and_dop_stays_below_one(model):
    rng = np.random.default_rng(7)
    ang = np.column_stack([rng.uniform(0, 1.5, 400), rng.uniform(0, 1.5, 400), rng.uniform(0, 2 * np.pi, 400)])
    wi, wo = _dirs(ang)
    M, e1 = mueller_brdf(model, wi, wo)
    f_s, f_p = model.brdf(wi, wo, "s"), model.brdf(wi, wo, "p")
    np.testing.assert_allclose(M[:, 0, 0], model.brdf(wi, wo, "u"), rtol=1e-12)  # unpolarized = mean
    np.testing.assert_allclose(M[:, 0, 0] + M[:, 0, 1], f_s, rtol=1e-10)
    np.testing.assert_allclose(M[:, 0, 0] - M[:, 0, 1], f_p, rtol=1e-10)
    np.testing.assert_allclose(np.einsum("ij,ij->i", e1, wo), 0, atol=1e-12)
    # every fully polarized input (random points on the Poincare sphere) leaves with DOP <= 1
    v = rng.normal(size=(400, 3))
    S = np.column_stack([np.ones(400), v / np.linalg.norm(v, axis=1)[:, None]])
    So = np.einsum("nij,nj->ni", M, S)
    assert np.all(np.linalg.norm(So[:, 1:], axis=1) <= So[:, 0] * (1 + 1e-12) + 1e-300)
    assert np.all(So[:, 0] >= -1e-15)
    # the cross terms exist out of the plane of incidence (45 deg in, 30 deg out, 30 deg azimuth)
    wi1, wo1 = _dirs(np.deg2rad(np.array([[45.0, 30.0, 30.0]])))
    M1, _ = mueller_brdf(Z302B, wi1, wo1)
    assert abs(M1[0, 0, 2]) > 0.1 * M1[0, 0, 0]


def test_which_materials_polarize():
    assert is_polarizing(Z302B)
    assert not is_polarizing(load_material({"name": "b", "components": [{"type": "lambertian", "rd": 0.05}]}))
    assert not is_polarizing(load_material({"name": "r", "wavelength_nm": 532.0, "components": [
        {"type": "k_correlation", "sigma_nm": 10.0, "lc_um": 2.0, "s": 2.6, "r": 0.04}]}))


@pytest.mark.parametrize("model", [Z302B, GLOSSY_PAINT], ids=["z302b", "lambert+kcorr+abg"])
def test_first_row_only_is_the_full_matrix_row_bit_for_bit(model):
    """Next-event estimation asks only for the scattered power M[0] . S: the first row alone is the same
    numbers as the full matrix's (the same products), the other rows zero."""
    rng = np.random.default_rng(11)
    ang = np.column_stack([rng.uniform(0, 1.5, 300), rng.uniform(0, 1.5, 300), rng.uniform(0, 2 * np.pi, 300)])
    wi, wo = _dirs(ang)
    full, e1 = mueller_brdf(model, wi, wo)
    row, e1_row = mueller_brdf(model, wi, wo, first_row_only=True)
    assert np.array_equal(row[:, 0, :], full[:, 0, :]) and np.array_equal(e1_row, e1)
    assert not row[:, 1:, :].any() and full[:, 1:, :].any()
    J, _ = rayleigh_rice_jones(wi, wo, complex(1.6, 0.3))
    assert np.array_equal(jones_to_mueller(J, first_row_only=True)[:, 0], jones_to_mueller(J)[:, 0])


def _edge_directions(rng, m):
    """Random wi (above) and wo (half below the horizon), with normal incidence, scatter along the
    normal, the specular direction and a near-normal wi among them."""
    def unit(n):
        d = rng.normal(size=(n, 3))
        return d / np.linalg.norm(d, axis=1, keepdims=True)
    wi, wo = unit(m), unit(m)
    wi[:, 2] = np.abs(wi[:, 2])
    wo[: m // 2, 2] = np.abs(wo[: m // 2, 2])
    wi[:50] = [0.0, 0.0, 1.0]
    wo[30:80] = [0.0, 0.0, 1.0]
    wo[100:120] = wi[100:120] * [-1.0, -1.0, 1.0]
    wi[200:210] = [1e-20, 0.0, 1.0]
    return wi, wo


@pytest.mark.parametrize("first_row_only", [False, True], ids=["full", "row0"])
@pytest.mark.parametrize("n", [1.55, 1.0, complex(1.6, 0.3), complex(0.96, 6.69)],
                         ids=["glass", "vacuum", "absorbing", "aluminium"])
def test_compiled_mueller_is_the_numpy_twins(n, first_row_only):
    """One compiled pass per ray gives the numpy twin's matrices and e1: bit for bit for a real index
    (NaN where the twin has NaN, below the horizon), within 1e-13 for a complex one (|M_ij| <= 1)."""
    wi, wo = _edge_directions(np.random.default_rng(5), 20_000)
    for s_in in (None, s_basis(-wi)):
        got, e1 = rayleigh_rice_mueller(wi, wo, n, s_in, None, first_row_only)
        with np.errstate(all="ignore"):
            want, e1_want = rayleigh_rice_mueller_numpy(wi, wo, n, s_in, None, first_row_only)
        np.testing.assert_array_equal(e1, e1_want)
        if isinstance(n, float):
            np.testing.assert_array_equal(got, want)
        else:
            np.testing.assert_allclose(got, want, rtol=0.0, atol=1e-13)  # |M_ij| <= M00 = 1
        above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        assert np.isfinite(want[above]).all()
        assert (got[above, 0, 0] == 0.0).all() if n == 1.0 else (got[above, 0, 0] == 1.0).all()


MIXED_INDICES = load_material({"name": "q", "wavelength_nm": 532.0, "components": [
    {"type": "k_correlation", "sigma_nm": 10.0, "lc_um": 2.0, "s": 2.6, "n": 1.5},
    {"type": "k_correlation", "sigma_nm": 5.0, "lc_um": 40.0, "s": 2.2, "n": 1.5},
    {"type": "lambertian", "rd": 0.05},
    {"type": "k_correlation", "sigma_nm": 8.0, "lc_um": 9.0, "s": 3.0, "n": 1.7},
    {"type": "k_correlation", "sigma_nm": 3.0, "lc_um": 90.0, "s": 2.4, "n": 1.5}]})


def _mueller_brdf_numpy(model, wi, wo, first_row_only):
    """The material's Mueller BRDF summed component by component with the numpy twin (the sum as
    ``mueller_brdf`` defines it, in component order)."""
    s_in = s_basis(-wi)
    e1 = s_basis(wo, fallback=s_in)
    M = np.zeros((len(wi), 4, 4))
    for c in model.lobes:
        if getattr(c, "n", None) is not None:
            Mn, _ = rayleigh_rice_mueller_numpy(wi, wo, c._index, s_in, e1, first_row_only)
            if first_row_only:
                M[:, 0, :] += c.brdf(wi, wo, "u")[:, None] * Mn[:, 0, :]
            else:
                M += c.brdf(wi, wo, "u")[:, None, None] * Mn
        else:
            fs, fp = c.brdf(wi, wo, "s"), c.brdf(wi, wo, "p")
            M[:, 0, 0] += 0.5 * (fs + fp)
            M[:, 0, 1] += 0.5 * (fs - fp)
    return M, e1


@pytest.mark.parametrize("first_row_only", [False, True], ids=["full", "row0"])
@pytest.mark.parametrize("model", [Z302B, GLOSSY_PAINT, MIXED_INDICES], ids=["z302b", "lambert+kcorr+abg", "mixed"])
def test_material_mueller_is_the_component_sum_bit_for_bit(model, first_row_only):
    """``mueller_brdf`` forms each substrate index's normalised matrix once for a run of components
    (z302's two lobes share n = 1.55) and adds them in component order: numpy's sum of the twin's
    matrices, bit for bit."""
    wi, wo = _edge_directions(np.random.default_rng(8), 5000)
    got, e1 = mueller_brdf(model, wi, wo, first_row_only=first_row_only)
    with np.errstate(all="ignore"):
        want, e1_want = _mueller_brdf_numpy(model, wi, wo, first_row_only)
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(e1, e1_want)
    assert (got[:, 0, 0] > 0).sum() > 2000


def test_compiled_s_basis_is_the_numpy_formulas():
    """The s vectors k x z (normalised) of the compiled pass are :func:`s_basis_numpy`'s bits (signed zeros
    included): random directions, along +-z and within 1e-12 of it (the fallback's rows, or the x-based rule
    without one), -0 components, NaN, and an empty batch."""
    from materials.rayleigh_rice import s_basis, s_basis_numpy

    rng = np.random.default_rng(12)
    n = 50_000
    k = rng.normal(size=(n, 3))
    k /= np.linalg.norm(k, axis=1)[:, None]
    k[:10], k[10:20], k[20:30] = [0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1e-13, -2e-13, 1.0]
    k[30:40, 0], k[40:50, 1], k[50:52] = -0.0, -0.0, np.nan
    fallback = rng.normal(size=(n, 3))
    fallback /= np.linalg.norm(fallback, axis=1)[:, None]
    for fb in (None, fallback):
        got, want = s_basis(k, fb), s_basis_numpy(k, fb)
        np.testing.assert_array_equal(got, want)
        assert np.array_equal(np.signbit(got), np.signbit(want))
    np.testing.assert_allclose(s_basis(k[:30], fallback[:30])[:20], fallback[:20], rtol=0, atol=1e-15)
    assert s_basis(k[:0]).shape == (0, 3) and s_basis(k[:0], fallback[:0]).shape == (0, 3)
