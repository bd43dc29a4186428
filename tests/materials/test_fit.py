"""Fitting: known-parameter recovery with s and p and one n, flagged points, analytic stderr, errors."""
import time

import numpy as np
import pytest

from materials.base import directions_from_angles
from materials.fit import FitError, ModelSpec, fit
from materials.kcorrelation import KCorrelation
from materials.lambertian import Lambertian
from materials.microfacet import Microfacet
from materials.scan import make_scan

TRUTH = {"lambertian.rd": 0.03, "k_correlation.sigma_nm": 8.0, "k_correlation.lc_um": 6.0,
         "k_correlation.s": 2.8, "n": 1.55}


def _synthetic(components, theta_i_deg=(10, 30, 50, 70), pols="sp", rel_noise=0.04, seed=3, n_per=60):
    """Scan by direct model evaluation, 60 points per (theta_i, pol) from -85 to 85 deg (negative =
    backscatter side), dense near specular like the paper's plan, with relative Gaussian noise."""
    ti, tr, pol = [], [], []
    for t in theta_i_deg:
        near = t + np.linspace(-4, 4, n_per // 3)
        far = np.linspace(-85, 85, n_per - len(near))
        for p in pols:
            r = np.concatenate([far, near[near < 89]])
            ti.append(np.full(len(r), float(t))); tr.append(r); pol.append(np.full(len(r), p))
    ti, tr, pol = map(np.concatenate, (ti, tr, pol))
    wi, wo = directions_from_angles(np.radians(ti), np.radians(np.abs(tr)), np.where(tr < 0, np.pi, 0.0))
    f = np.zeros(len(ti))
    for p in pols:
        m = pol == p
        f[m] = sum(c.brdf(wi[m], wo[m], p) for c in components)
    assert np.all(f > 0)
    meas = f * (1 + rel_noise * np.random.default_rng(seed).standard_normal(len(f)))
    return make_scan(wavelength_nm=532.0, polarization=pol, theta_i_deg=ti, theta_r_deg=tr, phi_r_deg=0.0,
                     brdf_per_sr=meas, brdf_std_per_sr=rel_noise * f, n_repeats=3)


def _truth_components():
    return [Lambertian(rd=TRUTH["lambertian.rd"]),
            KCorrelation(sigma_nm=TRUTH["k_correlation.sigma_nm"], lc_um=TRUTH["k_correlation.lc_um"],
                         s=TRUTH["k_correlation.s"], n=TRUTH["n"], wavelength_nm=532.0)]


def test_fit_recovers_known_parameters_within_3_sigma():
    scan = _synthetic(_truth_components())
    t0 = time.perf_counter()
    res = fit(scan, "lambertian+k_correlation", seed=1)
    elapsed = time.perf_counter() - t0
    assert res.success and res.n_excluded == 0 and res.n_points == len(scan)
    for name, true in TRUTH.items():
        err = res.stderr[name]
        assert 0 < err < 0.1 * true, name  # sanity: a real, finite, informative uncertainty
        assert abs(res.params[name] - true) < 3 * err, (name, res.params[name], err)
    # noise is 4 % -> 0.017 dex rms per point; the fit should sit at that level, and chi2/dof ~ 1
    for key, rms in res.rms_log10.items():
        assert 0.010 < rms < 0.025, key
    assert 0.8 < res.chi2_reduced < 1.2
    assert set(res.rms_log10) == {(t, p) for t in (10.0, 30.0, 50.0, 70.0) for p in "sp"}
    assert elapsed < 20.0  # a clean paper-sized scan fits in seconds
    assert res.rho["s"][0] == pytest.approx(res.rho["p"][0], rel=1e-6)  # s = p at normal incidence
    mat = res.material("synthetic")
    assert [c["type"] for c in mat.to_dict()["components"]] == ["lambertian", "k_correlation"]


def test_lambertian_stderr_matches_analytic_formula():
    """One free parameter, constant log-space sigma: the estimate of log10 rd is the mean of
    log10(pi f_meas) and its standard error is sigma_log10 / sqrt(N), i.e.
    stderr(rd) = rd ln(10) sigma_log10 / sqrt(N) = rd * rel / sqrt(N) (weighted least squares)."""
    rel = 0.05
    scan = _synthetic([Lambertian(rd=0.04)], rel_noise=rel, pols="u", seed=11)
    res = fit(scan, "lambertian", seed=0, n_starts=1, reweight=False)
    n = len(scan)
    # weights: std / measured (reweight off); the analytic mean uses the same weights
    sig = (scan.brdf_std_per_sr / scan.brdf_per_sr) / np.log(10)
    w = 1 / sig**2
    log_rd = np.sum(w * np.log10(np.pi * scan.brdf_per_sr)) / np.sum(w)
    assert res.params["lambertian.rd"] == pytest.approx(10**log_rd, rel=1e-6)
    expected = 10**log_rd * np.log(10) / np.sqrt(np.sum(w))
    assert res.stderr["lambertian.rd"] == pytest.approx(expected, rel=1e-4)
    assert expected == pytest.approx(0.04 * rel / np.sqrt(n), rel=0.1)


def test_flagged_points_do_not_crash_and_are_counted():
    scan = _synthetic(_truth_components(), theta_i_deg=(30, 70))
    brdf = scan.brdf_per_sr.copy()
    brdf[[0, 5, 17]] = [np.nan, -2e-4, 0.0]
    bad = make_scan(wavelength_nm=532.0, polarization=scan.polarization, theta_i_deg=scan.theta_i_deg,
                    theta_r_deg=scan.theta_r_deg, phi_r_deg=0.0, brdf_per_sr=brdf,
                    brdf_std_per_sr=scan.brdf_std_per_sr, n_repeats=3)
    res = fit(bad, "lambertian+k_correlation", n_starts=2)
    assert res.n_excluded == 3 and res.n_points == len(scan) - 3
    assert np.all(np.isfinite(res.residuals))
    assert abs(res.params["n"] - 1.55) < 3 * res.stderr["n"]


def test_microfacet_model_recovers_its_parameters():
    truth = [Lambertian(rd=0.02), Microfacet(alpha=0.5, n=1.5, weight=2.0)]
    scan = _synthetic(truth, theta_i_deg=(10, 50, 70), pols="sp", seed=5, n_per=30)
    res = fit(scan, "lambertian+microfacet", seed=2, n_starts=3)
    for name, true in {"lambertian.rd": 0.02, "microfacet.alpha": 0.5, "microfacet.weight": 2.0, "n": 1.5}.items():
        assert 0 < res.stderr[name] < 0.2 * true
        assert abs(res.params[name] - true) < 3 * res.stderr[name], name


def test_spec_names_fixed_and_errors():
    spec = ModelSpec("lambertian+k_correlation+k_correlation", 532.0, fixed={"n": 1.5})
    assert "k_correlation2.lc_um" in spec.free_names and "n" not in spec.free_names
    assert len(spec.components(spec.starts({"rd": 0.02}, 1, 0)[0])) == 3
    with pytest.raises(FitError, match="abc"):
        ModelSpec("lambertian+abc", 532.0)
    with pytest.raises(FitError, match="k_correlation.sigm"):
        ModelSpec("lambertian+k_correlation", 532.0, fixed={"k_correlation.sigm": 1.0})
    scan = _synthetic([Lambertian(rd=0.03)], theta_i_deg=(30,), pols="u", n_per=6)
    with pytest.raises(FitError, match="usable points"):
        fit(scan.select(np.arange(3)), "lambertian+k_correlation")


def test_abg_lobe_recovers_its_parameters():
    from materials.abg import Abg

    truth = [Lambertian(rd=0.02), Abg(a=2e-3, b=1e-3, g=2.2)]
    scan = _synthetic(truth, theta_i_deg=(20, 60), pols="u", seed=8, n_per=45)
    res = fit(scan, "lambertian+abg", seed=0, n_starts=4)
    assert "n" not in res.params  # no component with a refractive index
    for name, true in {"lambertian.rd": 0.02, "abg.a": 2e-3, "abg.b": 1e-3, "abg.g": 2.2}.items():
        assert 0 < res.stderr[name] < 0.3 * true
        assert abs(res.params[name] - true) < 3 * res.stderr[name], name


def test_zero_and_unknown_std_use_the_documented_floor_and_default():
    """std 0 -> relative floor 0.5 %; std NaN -> 5 % (module docstring). With a constant relative
    sigma the Lambertian stderr is rd * rel / sqrt(N) (see the analytic test above)."""
    scan = _synthetic([Lambertian(rd=0.04)], rel_noise=0.01, pols="u", seed=2, theta_i_deg=(30,), n_per=40)
    n = len(scan)
    for std, rel in ((0.0, 0.005), (np.nan, 0.05)):
        s = make_scan(wavelength_nm=532.0, polarization="u", theta_i_deg=scan.theta_i_deg,
                      theta_r_deg=scan.theta_r_deg, brdf_per_sr=scan.brdf_per_sr, brdf_std_per_sr=std)
        res = fit(s, "lambertian", n_starts=1)
        assert np.all(np.isfinite(res.residuals))
        assert res.stderr["lambertian.rd"] == pytest.approx(res.params["lambertian.rd"] * rel / np.sqrt(n), rel=1e-3)
