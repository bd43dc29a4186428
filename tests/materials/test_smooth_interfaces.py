"""Fresnel amplitudes, Mueller matrices, and the ``specular`` / ``dielectric`` components.

References: PHYSICS §1 Fresnel table (n = 1.5); Born & Wolf §1.5 (Snell, Brewster, total
internal reflection, Stokes relations r' = -r, t t' = 1 - r^2); the normal-incidence metal
reflectance ((n-1)^2 + k^2) / ((n+1)^2 + k^2); a perfect conductor reflects E -> -E + 2 (n.E) n.
"""
import json

import numpy as np
import pytest

from materials import MaterialError, load_material
from materials.fresnel import fresnel_amplitudes, fresnel_power
from materials.mueller import interface_mueller, linear_stokes, rotate_stokes, rotation_mueller, s_vector
from materials.smooth import Dielectric, Specular, reflect, refract

DEG = np.pi / 180


def test_fresnel_power_matches_the_physics_table():
    """PHYSICS §1: n = 1.50, R_s and R_p at 0, 10, 30, 45, 60, 70, 80 deg (4 digits)."""
    th = np.deg2rad([0, 10, 30, 45, 60, 70, 80])
    Rs, Rp, Ts, Tp = fresnel_power(np.cos(th), 1.5)
    np.testing.assert_allclose(Rs, [0.0400, 0.0417, 0.0578, 0.0920, 0.1766, 0.2996, 0.5386], atol=6e-5)
    np.testing.assert_allclose(Rp, [0.0400, 0.0384, 0.0252, 0.0085, 0.0018, 0.0425, 0.2368], atol=6e-5)
    np.testing.assert_allclose(Rs + Ts, 1.0, atol=1e-14)
    np.testing.assert_allclose(Rp + Tp, 1.0, atol=1e-14)


def test_inside_glass_total_internal_reflection_and_energy():
    """From glass (m = 1/1.5): R + T = 1 below the critical angle asin(1/1.5) = 41.81 deg, R = 1 above."""
    th = np.deg2rad(np.linspace(0, 89.9, 400))
    Rs, Rp, Ts, Tp = fresnel_power(np.cos(th), 1 / 1.5)
    np.testing.assert_allclose(Rs + Ts, 1.0, atol=1e-12)
    np.testing.assert_allclose(Rp + Tp, 1.0, atol=1e-12)
    crit = np.arcsin(1 / 1.5)
    assert np.all(Ts[th > crit + 1e-9] == 0) and np.all(Tp[th > crit + 1e-9] == 0)
    np.testing.assert_allclose(Rs[th > crit + 1e-9], 1.0, atol=1e-12)


def test_brewster_angle_reflects_no_p():
    """tan(theta_B) = n: R_p = 0 from outside (56.31 deg) and from inside (33.69 deg)."""
    for m in (1.5, 1 / 1.5):
        Rs, Rp, _, _ = fresnel_power(np.array([np.cos(np.arctan(m))]), m)
        assert Rp[0] < 1e-28 and Rs[0] > 0.1


def test_stokes_relations():
    """Born & Wolf: r(inside) = -r(outside) at the Snell-related angle; t t' = 1 - r^2."""
    th = np.deg2rad([5, 20, 35, 40])
    c = np.cos(th)
    rs, rp, ts, tp, q = fresnel_amplitudes(c, 1.5)
    ct = (q / 1.5).real
    rs2, rp2, ts2, tp2, _ = fresnel_amplitudes(ct, 1 / 1.5)
    np.testing.assert_allclose(rs2, -rs, atol=1e-14)
    np.testing.assert_allclose(rp2, -rp, atol=1e-14)
    np.testing.assert_allclose(ts * ts2, 1 - rs**2, atol=1e-14)
    np.testing.assert_allclose(tp * tp2, 1 - rp**2, atol=1e-14)


def test_metal_normal_incidence_and_perfect_conductor_signs():
    n, k = 0.96, 6.69
    coef = Specular(n=[n, k]).coefficients(np.array([1.0]))
    R = ((n - 1) ** 2 + k**2) / ((n + 1) ** 2 + k**2)
    np.testing.assert_allclose(coef.R_s, R, rtol=1e-12)
    np.testing.assert_allclose(coef.R_p, R, rtol=1e-12)
    # a near-perfect conductor at 40 deg: build the reflected field E_r = -E + 2 (n.E) n and read
    # it in the (s, p = d x s) basis of the reflected ray; the coefficients must agree
    th = 40 * DEG
    d = np.array([[np.sin(th), 0.0, -np.cos(th)]])
    nrm = np.array([[0.0, 0.0, 1.0]])
    s = s_vector(d, nrm)
    dr = reflect(d, nrm)
    p_i, p_r = np.cross(d, s), np.cross(dr, s)
    for e_in, amp_of in ((s, lambda c: c.r_s), (p_i, lambda c: c.r_p)):
        e_r = -e_in + 2 * np.sum(nrm * e_in) * nrm
        basis = s if e_in is s else p_r
        coef = Specular(n=[1e-3, 1e5]).coefficients(np.array([np.cos(th)]))
        np.testing.assert_allclose(amp_of(coef).real, np.sum(e_r * basis), atol=1e-4)
    c = Specular(r=0.9).coefficients(np.array([0.3]))
    np.testing.assert_allclose([c.r_s[0], c.r_p[0]], [-np.sqrt(0.9), np.sqrt(0.9)])


def test_refract_obeys_snell_and_stays_in_the_plane():
    rng = np.random.default_rng(3)
    d = rng.normal(size=(50, 3))
    d[:, 2] = -np.abs(d[:, 2]) - 0.2
    d /= np.linalg.norm(d, axis=1)[:, None]
    n = np.tile([0.0, 0.0, 1.0], (50, 1))
    coef = Dielectric(n=1.5).coefficients(-d[:, 2])
    t = refract(d, n, coef.eta, coef.cos_t)
    sin_i = np.linalg.norm(np.cross(d, n), axis=1)
    sin_t = np.linalg.norm(np.cross(t, n), axis=1)
    np.testing.assert_allclose(sin_i, 1.5 * sin_t, atol=1e-12)
    np.testing.assert_allclose(np.einsum("ij,ij->i", np.cross(d, n), t), 0, atol=1e-12)  # coplanar
    assert np.all(t[:, 2] < 0)


def test_mueller_of_fresnel_reflection():
    """M @ (1, 1, 0, 0) = R_s (1, 1, 0, 0); unpolarized = mean of two orthogonal linear inputs at
    any frame angle; a rotation keeps S0 and the degree of polarization."""
    th = np.deg2rad([10, 45, 70])
    rs, rp, *_ = fresnel_amplitudes(np.cos(th), 1.5)
    M = interface_mueller(rs, rp)
    out = M @ np.array([1.0, 1.0, 0.0, 0.0])
    np.testing.assert_allclose(out[:, 0], np.abs(rs) ** 2)
    np.testing.assert_allclose(out[:, 1], np.abs(rs) ** 2)
    for a in (0.3, 1.1):
        e1 = np.array([1.0, np.cos(2 * a), np.sin(2 * a), 0.0])
        e2 = np.array([1.0, -np.cos(2 * a), -np.sin(2 * a), 0.0])
        np.testing.assert_allclose(0.5 * (M @ e1 + M @ e2), M @ np.array([1.0, 0, 0, 0]), atol=1e-15)
    S = np.array([[1.0, 0.3, -0.4, 0.5]])
    R = rotation_mueller(np.array([np.cos(0.7)]), np.array([np.sin(0.7)]))
    S2 = (R @ S[0])[0]
    assert S2[0] == 1.0 and np.isclose(np.linalg.norm(S2[1:]), np.linalg.norm(S[0, 1:]))


def test_rotate_stokes_and_linear_stokes():
    d = np.array([[0.0, 0.0, 1.0]])
    ex, ey = np.array([[1.0, 0, 0]]), np.array([[0.0, 1, 0]])
    e45 = (ex + ey) / np.sqrt(2)
    S = linear_stokes(e45, d, ex)
    np.testing.assert_allclose(S, [[1, 0, 1, 0]], atol=1e-15)
    np.testing.assert_allclose(rotate_stokes(S, ex, e45, d), [[1, 1, 0, 0]], atol=1e-15)
    np.testing.assert_allclose(rotate_stokes(linear_stokes(ey, d, ex), ex, ey, d), [[1, 1, 0, 0]], atol=1e-15)


# ---------------------------------------------------------------- material files


def _mirror(extra=()):
    return {"name": "al", "wavelength_nm": 532.0,
            "components": [{"type": "specular", "n": [0.96, 6.69]}, *extra]}


def test_specular_and_dielectric_load_from_json(tmp_path):
    p = tmp_path / "bk7.json"
    p.write_text(json.dumps({"name": "n_bk7", "wavelength_nm": 532.0,
                             "components": [{"type": "dielectric", "n": 1.5195, "absorption_per_mm": 0.001}]}))
    m = load_material(p)
    assert isinstance(m.smooth, Dielectric) and m.lobes == () and m.composite is None
    th = np.deg2rad([0.0, 30.0, 60.0])
    np.testing.assert_allclose(m.reflectance(th, "u") + m.transmittance(th, "u"), 1.0, atol=1e-14)
    assert m.to_dict()["components"][0] == {"type": "dielectric", "n": 1.5195, "absorption_per_mm": 0.001}
    assert load_material(_mirror()).smooth.index == complex(0.96, 6.69)


@pytest.mark.parametrize("entry, key", [
    ({"type": "specular", "n": 1.5, "r": 0.5}, "exactly one"),
    ({"type": "specular", "r": 1.2}, "'r'"),
    ({"type": "specular", "r": 0.9, "weigth": 1.0}, "weigth"),
    ({"type": "dielectric", "n": 1.5, "n_out": 1.0}, "n_out"),
    ({"type": "dielectric", "n": [1.5]}, "'n'"),
])
def test_bad_smooth_components_are_one_line_errors(entry, key):
    with pytest.raises(MaterialError, match=key) as exc:
        load_material({"name": "x", "components": [entry]})
    assert "components[0]" in str(exc.value) and "\n" not in str(exc.value)


def test_at_most_one_delta_component():
    with pytest.raises(MaterialError, match=r"components\[1\].*at most one"):
        load_material({"name": "x", "components": [{"type": "specular", "r": 0.5}, {"type": "dielectric", "n": 1.5}]})


def test_scatter_lobes_take_their_energy_from_the_specular_part():
    """R' = R - rho_lobes for a mirror (total = R); a dielectric's R and T shrink in proportion
    (R' + T' + rho = 1); rho itself is the lobes' own quadrature (materials.albedo)."""
    lobe = {"type": "k_correlation", "sigma_nm": 5.0, "lc_um": 5.0, "s": 2.5, "n": [0.96, 6.69]}
    m = load_material(_mirror([lobe]))
    th = np.deg2rad([0.0, 20.0, 45.0, 70.0])
    for pol in ("s", "p"):
        rho = m.albedo(th, pol)
        R = {"s": 0, "p": 1}[pol]
        R0 = Specular(n=[0.96, 6.69]).coefficients(np.cos(th))
        R0 = R0.R_s if pol == "s" else R0.R_p
        assert np.all(rho > 1e-3)
        np.testing.assert_allclose(m.reflectance(th, pol), R0, rtol=3e-3)  # table interpolation
    g = load_material({"name": "g", "wavelength_nm": 532.0, "components": [
        {"type": "dielectric", "n": 1.5}, {"type": "lambertian", "rd": 0.1}]})
    th = np.deg2rad([0.0, 50.0])
    np.testing.assert_allclose(g.reflectance(th, "s") + g.transmittance(th, "s"), 1.0, atol=1e-12)
    c = Dielectric(n=1.5).coefficients(np.cos(th))
    np.testing.assert_allclose(g.smooth_coefficients(np.cos(th)).R_s / c.R_s, 0.9, rtol=1e-12)
    np.testing.assert_allclose(g.smooth_coefficients(np.cos(th)).T_s / c.T_s, 0.9, rtol=1e-12)
    # lobes stronger than the mirror: the specular part vanishes, the total is the lobes' rho < 1
    weak = load_material({"name": "w", "components": [{"type": "specular", "r": 0.05}, {"type": "lambertian", "rd": 0.3}]})
    np.testing.assert_allclose(weak.reflectance(np.array([0.3]), "u"), 0.3, rtol=1e-9)


def test_material_eval_dhr_includes_the_specular_part(tmp_path):
    """CONTRACTS §4.2: dhr of a bare aluminium mirror at normal incidence is the Fresnel R."""
    import subprocess
    import sys

    p = tmp_path / "al.json"
    p.write_text(json.dumps(_mirror()))
    out = tmp_path / "o.json"
    r = subprocess.run([sys.executable, "-m", "straylight.cli.main", "material", "eval", str(p), "--theta-i-deg", "0",
                        "--theta-r-deg", "10", "--polarization", "u", "--json", str(out)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    d = json.loads(out.read_text())
    n, k = 0.96, 6.69
    assert d["dhr"] == pytest.approx(((n - 1) ** 2 + k**2) / ((n + 1) ** 2 + k**2), rel=1e-9)
    assert d["brdf_per_sr"] == [0.0] and d["transmittance"] == 0.0


def test_compiled_reflect_and_refract_are_the_numpy_formulas():
    """The compiled mirror and Snell directions give their numpy twins' bits (signed zeros included):
    random directions and normals, normal incidence, zero and -0 components, grazing, per-row and
    scalar eta and cos_t, and an empty batch."""
    from materials.smooth import reflect_numpy, refract_numpy

    rng = np.random.default_rng(17)
    n = 50_000
    d, nrm = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    d[:100], nrm[:50] = [0.0, 0.0, -1.0], [0.0, 0.0, 1.0]
    d[100:200, 0], d[200:300, 1] = 0.0, -0.0
    nrm = np.where((np.einsum("ij,ij->i", d, nrm) > 0)[:, None], -nrm, nrm)
    nrm[300:310] = np.cross(d[300:310], [1.0, 0.0, 0.0])  # grazing
    eta = rng.uniform(0.5, 1.6, n)
    cos_i = -np.einsum("ij,ij->i", d, nrm)
    cos_t = np.sqrt(np.maximum(0.0, 1.0 - eta**2 * (1.0 - cos_i**2)))
    got, want = reflect(d, nrm), reflect_numpy(d, nrm)
    assert np.array_equal(got, want) and np.array_equal(np.signbit(got), np.signbit(want))
    for e, c in ((eta, cos_t), (1.0 / 1.5, cos_t), (eta, 0.5)):
        got, want = refract(d, nrm, e, c), refract_numpy(d, nrm, e, c)
        assert np.array_equal(got, want) and np.array_equal(np.signbit(got), np.signbit(want))
    assert reflect(d[:0], nrm[:0]).shape == (0, 3) and refract(d[:0], nrm[:0], eta[:0], cos_t[:0]).shape == (0, 3)


def test_compiled_dielectric_coefficients_are_the_numpy_formulas():
    """A real index without a coating: the compiled pass gives :meth:`Dielectric.coefficients_numpy`'s
    bits (signed zeros included) from the front and the back, for random cosines, normal and grazing
    incidence, total internal reflection and its edge, cosines outside [0, 1], NaN and an empty batch."""
    from materials.smooth import Dielectric

    rng = np.random.default_rng(23)
    c = rng.uniform(0.0, 1.0, 100_000)
    c[:10], c[10:20], c[20:30], c[30:35] = 1.0, 0.0, -0.0, np.nan
    c[35:40], c[40:45] = -0.3, 1.2
    crit = np.sqrt(1.0 - (1.0 / 1.5195) ** 2)  # the back side's critical cosine and its neighbours
    c[45:48] = [crit, np.nextafter(crit, 0.0), np.nextafter(crit, 1.0)]
    for model in (Dielectric(n=1.5195), Dielectric(n=1.5195, n_outside=1.33), Dielectric(n=1.0)):
        for back in (False, True):
            got, want = model.coefficients(c, back=back), model.coefficients_numpy(c, back=back)
            for name in ("r_s", "r_p", "t_s", "t_p", "cos_t", "eta"):
                g, w = getattr(got, name), getattr(want, name)
                assert g.dtype == w.dtype and g.shape == w.shape, name
                for part_g, part_w in ((np.real(g), np.real(w)), (np.imag(g), np.imag(w))):
                    np.testing.assert_array_equal(part_g, part_w, err_msg=name)
                    assert np.array_equal(np.signbit(part_g), np.signbit(part_w)), name
    assert Dielectric(n=1.5195).coefficients(c[:0]).r_s.shape == (0,)
    assert (Dielectric(n=1.5195).coefficients(c, back=True).t_s[c < crit * 0.99] == 0).all()  # TIR
