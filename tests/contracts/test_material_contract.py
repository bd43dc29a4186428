"""CONTRACTS §5 material files and §4.2 ``straylight material eval``, with new materials.

Golden values: closed forms of CONTRACTS §5 / PHYSICS.md §1 written out here (Lambertian rd/pi,
ABg, Harvey-Shack, Dittman K-correlation with constant R), the NIST SCATMECH table of PHYSICS.md §1,
Fresnel for a complex index, and scipy quadrature for the directional-hemispherical reflectance.
"""
import json
import math

import numpy as np
import pytest
from scipy import integrate

from contract_helpers import assert_one_line_error, write_json


def _beta_dist(ti, tr, phi):
    """|beta - beta0| (PHYSICS.md §1), radians in."""
    return np.hypot(np.sin(tr) * np.cos(phi) - np.sin(ti), np.sin(tr) * np.sin(phi))


def _eval(cli, tmp_path, model, ti, trs, pol, phis=None, name="out.json"):
    out = tmp_path / name
    argv = ["material", "eval", model, "--theta-i-deg", ti, "--theta-r-deg", *trs, "--polarization", pol,
            "--json", out]
    if phis is not None:
        argv += ["--phi-r-deg", *phis]
    rc, _, err = cli(*argv)
    assert rc == 0, err
    doc = json.loads(out.read_text())
    for key in ("brdf_per_sr", "theta_r_deg", "dhr"):
        assert key in doc, f"OUT.json lacks {key!r}"
    assert doc["theta_r_deg"] == pytest.approx([float(t) for t in trs])
    assert len(doc["brdf_per_sr"]) == len(trs)
    assert isinstance(doc["dhr"], float)
    return np.array(doc["brdf_per_sr"]), doc["dhr"]


def test_lambertian_value_and_dhr(cli, tmp_path):
    m = write_json(tmp_path / "grey.json", {"name": "grey", "components": [{"type": "lambertian", "rd": 0.07}]})
    for pol in "spu":
        f, dhr = _eval(cli, tmp_path, m, 35, [-80, -10, 0, 35, 89], pol)
        np.testing.assert_allclose(f, 0.07 / math.pi, rtol=1e-12)
        assert dhr == pytest.approx(0.07, rel=2e-3)  # rho = rd for a Lambertian


def test_abg_closed_form_in_and_out_of_plane(cli, tmp_path):
    a, b, g = 0.002, 3e-4, 1.7
    m = write_json(tmp_path / "abg.json", {"name": "abg1", "wavelength_nm": 633.0,
                                           "components": [{"type": "abg", "a": a, "b": b, "g": g}]})
    trs = [0.0, 15.0, 19.0, 20.0, 21.5, 60.0]
    phis = [0.0, 0.0, 0.0, 0.0, 10.0, 120.0]
    f, dhr = _eval(cli, tmp_path, m, 20, trs, "u", phis)
    x = _beta_dist(np.radians(20), np.radians(trs), np.radians(phis))
    np.testing.assert_allclose(f, a / (b + x ** g), rtol=1e-9)
    # dhr = int f cos(theta_r) dOmega over the hemisphere (scipy, independent of the project's grid)
    ti = np.radians(20)
    val, _ = integrate.dblquad(
        lambda t, p: a / (b + _beta_dist(ti, t, p) ** g) * np.cos(t) * np.sin(t),
        0, 2 * np.pi, 0, np.pi / 2, epsabs=1e-9, epsrel=1e-7)
    assert 0 < val < 1
    assert dhr == pytest.approx(val, rel=0.01)


def test_harvey_shack_closed_form(cli, tmp_path):
    b0, ell, s = 8.0, 0.02, -2.3
    m = write_json(tmp_path / "hs.json", {"name": "hs", "wavelength_nm": 1064.0,
                                          "components": [{"type": "harvey_shack", "b0": b0, "l": ell, "s": s}]})
    trs = [-40.0, 0.0, 44.0, 45.0, 46.0, 80.0]
    f, _ = _eval(cli, tmp_path, m, 45, trs, "s")
    x = _beta_dist(np.radians(45), np.radians(np.abs(trs)), np.where(np.array(trs) < 0, np.pi, 0.0))
    np.testing.assert_allclose(f, b0 * (1 + (x / ell) ** 2) ** (s / 2), rtol=1e-9)


def _dittman(R, lam_nm, sigma_nm, lc_um, s, ti, tr, phi):
    """PHYSICS.md §1, Dittman s != 2, dn = 2, in um."""
    lam, sig, B = lam_nm * 1e-3, sigma_nm * 1e-3, 2 * np.pi * lc_um
    pre = 2 * np.pi * 4 * R * B ** 2 / lam ** 4 * sig ** 2 * (s - 2) / (1 - (1 + (B / lam) ** 2) ** (1 - s / 2))
    x = _beta_dist(ti, tr, phi)
    return pre * np.cos(ti) * np.cos(tr) / (1 + B ** 2 * x ** 2 / lam ** 2) ** (s / 2)


def test_kcorrelation_constant_r_and_weight(cli, tmp_path):
    comp = {"type": "k_correlation", "sigma_nm": 4.0, "lc_um": 12.0, "s": 2.7, "r": 0.05}
    m1 = write_json(tmp_path / "k1.json", {"name": "k1", "wavelength_nm": 905.0, "components": [comp]})
    m2 = write_json(tmp_path / "k2.json", {"name": "k2", "wavelength_nm": 905.0,
                                           "components": [dict(comp, weight=0.25)]})
    trs = [25.0, 29.0, 30.0, 31.0, 50.0, -20.0]
    phis = [0.0, 0.0, 0.0, 7.0, 45.0, 0.0]
    expect = _dittman(0.05, 905.0, 4.0, 12.0, 2.7, np.radians(30), np.radians(np.abs(trs)),
                      np.radians(phis) + np.where(np.array(trs) < 0, np.pi, 0.0))
    for pol in "sp":  # constant R: no polarization dependence
        f1, _ = _eval(cli, tmp_path, m1, 30, trs, pol, phis)
        np.testing.assert_allclose(f1, expect, rtol=1e-9)
    f2, _ = _eval(cli, tmp_path, m2, 30, trs, "u", phis)
    np.testing.assert_allclose(f2, 0.25 * expect, rtol=1e-9)


# PHYSICS.md §1, NIST SCATMECH golden table: lambda 532 nm, n 1.5, sigma 10 nm, Lc 2 um, s 2.6, + Lambertian 0.03
SCATMECH = [(10, 10.0, 1.50838e-01, 1.39687e-01), (10, 20.0, 1.32037e-02, 1.26139e-02),
            (45, 47.0, 1.21033e-01, 1.81363e-02), (80, 82.0, 5.69068e-02, 3.23008e-02)]


@pytest.mark.parametrize("ti,tr,fs,fp", SCATMECH)
def test_kcorrelation_real_n_vs_scatmech(cli, tmp_path, ti, tr, fs, fp):
    m = write_json(tmp_path / "rr.json", {"name": "rr", "wavelength_nm": 532.0, "components": [
        {"type": "lambertian", "rd": 0.03},
        {"type": "k_correlation", "sigma_nm": 10.0, "lc_um": 2.0, "s": 2.6, "n": 1.5}]})
    f_s, _ = _eval(cli, tmp_path, m, ti, [tr], "s")
    f_p, _ = _eval(cli, tmp_path, m, ti, [tr], "p")
    f_u, _ = _eval(cli, tmp_path, m, ti, [tr], "u")
    assert f_s[0] == pytest.approx(fs, rel=2e-4)
    assert f_p[0] == pytest.approx(fp, rel=2e-4)
    assert f_u[0] == pytest.approx((fs + fp) / 2, rel=2e-4)  # unpolarized = mean (PHYSICS.md §1)


def test_kcorrelation_complex_n_specular_is_fresnel(cli, tmp_path):
    """At specular Q_ss = R_s, Q_pp = R_p (PHYSICS.md §1), here for an absorbing [n, k] substrate."""
    n, k, ti_deg = 1.8, 0.6, 50.0
    base = {"type": "k_correlation", "sigma_nm": 2.0, "lc_um": 5.0, "s": 2.4}
    mr = write_json(tmp_path / "r1.json", {"name": "r1", "wavelength_nm": 700.0, "components": [dict(base, r=1.0)]})
    mc = write_json(tmp_path / "nk.json", {"name": "nk", "wavelength_nm": 700.0,
                                           "components": [dict(base, n=[n, k])]})
    ti = np.radians(ti_deg)
    eps = complex(n, k) ** 2
    q = np.sqrt(eps - np.sin(ti) ** 2)
    rs = abs((np.cos(ti) - q) / (np.cos(ti) + q)) ** 2
    rp = abs((eps * np.cos(ti) - q) / (eps * np.cos(ti) + q)) ** 2
    ref, _ = _eval(cli, tmp_path, mr, ti_deg, [ti_deg], "s")
    for pol, R in (("s", rs), ("p", rp)):
        f, _ = _eval(cli, tmp_path, mc, ti_deg, [ti_deg], pol)
        assert f[0] / ref[0] == pytest.approx(R, rel=1e-6)


def test_phi_r_and_negative_theta_r(cli, tmp_path):
    m = write_json(tmp_path / "abg.json", {"name": "a", "components": [
        {"type": "abg", "a": 0.001, "b": 1e-3, "g": 2.0}, {"type": "lambertian", "rd": 0.01}]})
    back, _ = _eval(cli, tmp_path, m, 40, [30.0], "u", [180.0], name="b.json")
    neg, _ = _eval(cli, tmp_path, m, 40, [-30.0], "u", [0.0], name="n.json")
    fwd, _ = _eval(cli, tmp_path, m, 40, [30.0], "u", [0.0], name="f.json")
    assert back[0] == pytest.approx(neg[0], rel=1e-12)
    assert fwd[0] > back[0] > 0  # specular half-plane (phi_r = 0) is nearer the lobe


def test_components_sum(cli, tmp_path):
    comps = [{"type": "lambertian", "rd": 0.02}, {"type": "abg", "a": 5e-4, "b": 1e-3, "g": 1.5},
             {"type": "harvey_shack", "b0": 2.0, "l": 0.05, "s": -2.0},
             {"type": "k_correlation", "sigma_nm": 3.0, "lc_um": 40.0, "s": 2.4, "n": 1.52, "weight": 0.5}]
    trs = [-60.0, 0.0, 30.0, 33.0, 70.0]
    total, _ = _eval(cli, tmp_path, write_json(tmp_path / "all.json", {"name": "all", "wavelength_nm": 532.0,
                                                                       "components": comps}), 33, trs, "p")
    parts = sum(_eval(cli, tmp_path, write_json(tmp_path / f"c{i}.json", {"name": f"c{i}", "wavelength_nm": 532.0,
                                                                           "components": [c]}), 33, trs, "p")[0]
                for i, c in enumerate(comps))
    np.testing.assert_allclose(total, parts, rtol=1e-12)


@pytest.mark.parametrize("data,needles", [
    ({"name": "x", "components": [{"type": "lambertian", "rd": 0.1, "rdd": 0.2}]}, ["rdd"]),
    ({"name": "x", "colour": "black", "components": [{"type": "lambertian", "rd": 0.1}]}, ["colour"]),
    ({"name": "x", "components": [{"type": "lambertain", "rd": 0.1}]}, ["lambertain"]),
    ({"name": "x", "components": [{"type": "lambertian", "rd": -0.1}]}, ["rd"]),
    ({"name": "x", "components": [{"type": "lambertian", "rd": "dark"}]}, ["rd"]),
    ({"name": "x", "wavelength_nm": 532, "components": [
        {"type": "k_correlation", "sigma_nm": 3.0, "lc_um": 4.0, "s": 2.4, "n": 1.5, "r": 0.04}]}, ["components[0]"]),
    ({"name": "x", "wavelength_nm": 532, "components": [
        {"type": "k_correlation", "sigma_nm": -3.0, "lc_um": 4.0, "s": 2.4, "n": 1.5}]}, ["sigma_nm"]),
    ({"name": "x", "wavelength_nm": 532, "components": [
        {"type": "k_correlation", "sigma_nm": 3.0, "lc_um": 4.0, "s": 2.4, "n": [1.5]}]}, ["n"]),
    ({"name": "x", "components": [{"type": "abg", "a": 1e-3, "b": 1e-3}]}, ["g"]),
    ({"name": "x", "components": []}, ["components"]),
    ({"name": "x", "components": [{"type": "lambertian", "rd": 1.2}]}, ["rd"]),
    ({"name": "x", "components": [{"type": "lambertian", "rd": 0.6}, {"type": "lambertian", "rd": 0.6}]},
     ["energy"]),
])
def test_bad_material_file_one_line_error(cli, tmp_path, data, needles):
    m = write_json(tmp_path / "bad.json", data)
    rc, _, err = cli("material", "eval", m, "--theta-i-deg", 10, "--theta-r-deg", 10, "--polarization", "s",
                     "--json", tmp_path / "o.json")
    assert_one_line_error(rc, err, "bad.json", *needles)
    assert not (tmp_path / "o.json").exists()


def test_invalid_json_names_line_and_column(cli, tmp_path):
    m = tmp_path / "broken.json"
    m.write_text('{"name": "x",\n "components": [\n  {"type": "lambertian", "rd": 0.1,}\n ]\n}\n')
    rc, _, err = cli("material", "eval", m, "--theta-i-deg", 10, "--theta-r-deg", 10, "--polarization", "s",
                     "--json", tmp_path / "o.json")
    assert_one_line_error(rc, err, "broken.json", ":3:")


@pytest.mark.parametrize("extra", [["--theta-r-deg", "95"], ["--polarization", "x"], ["--theta-i-deg", "-5"],
                                   ["--phi-r-deg", "0", "90"]])
def test_bad_eval_options(cli, tmp_path, extra):
    m = write_json(tmp_path / "g.json", {"name": "g", "components": [{"type": "lambertian", "rd": 0.1}]})
    argv = {"--theta-i-deg": ["10"], "--theta-r-deg": ["10", "20", "30"], "--polarization": ["s"]}
    argv[extra[0]] = extra[1:]
    flat = ["material", "eval", m, "--json", tmp_path / "o.json"] + [x for k, v in argv.items() for x in [k, *v]]
    rc, _, err = cli(*flat)
    assert rc != 0
    assert "Traceback" not in err
    assert not (tmp_path / "o.json").exists()


def test_preset_names_evaluate(cli, tmp_path):
    from materials import list_presets

    names = list_presets()
    assert names
    for name in names:
        f, dhr = _eval(cli, tmp_path, name, 30, [30.0, 60.0], "u")
        assert np.all(f > 0) and 0 < dhr < 1


@pytest.mark.parametrize("ti_deg", [0.0, 40.0])
def test_dhr_narrow_kcorrelation_lobe_vs_scipy(cli, tmp_path, ti_deg):
    """dhr = integral of the BRDF over projected solid angle = d^2 beta on the unit disk (scipy, polar
    coordinates about beta0) for a narrow lobe (B / lambda ~ 470), Dittman's formula with constant R."""
    lam_nm, sigma_nm, lc_um, s, R = 532.0, 3.0, 40.0, 2.4, 0.9
    m = write_json(tmp_path / "narrow.json", {"name": "narrow", "wavelength_nm": lam_nm, "components": [
        {"type": "k_correlation", "sigma_nm": sigma_nm, "lc_um": lc_um, "s": s, "r": R}]})
    _, dhr = _eval(cli, tmp_path, m, ti_deg, [ti_deg], "s")
    lam, B = lam_nm * 1e-3, 2 * np.pi * lc_um
    pre = 8 * np.pi * R * B ** 2 / lam ** 4 * (sigma_nm * 1e-3) ** 2 * (s - 2) / (1 - (1 + (B / lam) ** 2) ** (1 - s / 2))
    ti = np.radians(ti_deg)
    b0 = np.sin(ti)

    def along(phi):
        c = np.cos(phi)
        rmax = -b0 * c + np.sqrt(b0 * b0 * c * c - b0 * b0 + 1)

        def g(r):
            return r * pre * np.cos(ti) * np.sqrt(max(0.0, 1 - (b0 * b0 + 2 * b0 * r * c + r * r))) \
                / (1 + B * B * r * r / lam ** 2) ** (s / 2)

        pts = [x for x in (1e-4, 1e-3, 1e-2, 0.1) if x < rmax]
        return integrate.quad(g, 0, rmax, points=pts, limit=400, epsabs=1e-13, epsrel=1e-10)[0]

    expect = integrate.quad(along, 0, 2 * np.pi, limit=200, epsrel=1e-9)[0]
    assert 0 < expect < R
    assert dhr == pytest.approx(expect, rel=1e-4)
