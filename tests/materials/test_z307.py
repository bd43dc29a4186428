"""The Z307 reader against values read by eye from the source files (materials/data/README_z307.txt)."""
import numpy as np
import pytest

from materials.z307 import read_z307


def test_near_normal_level_is_brf_over_pi():
    scan = read_z307()  # control set, 630.79 nm
    # file row "10 0 2 180 0.028989": 10 deg in, 2 deg out, forward side
    i = np.flatnonzero((scan.theta_i_deg == 10) & (scan.theta_r_deg == 2))
    assert len(i) == 1
    assert scan.brdf_per_sr[i[0]] == pytest.approx(0.028989 / np.pi, rel=1e-12)
    assert scan.phi_r_deg[i[0]] == 0.0
    # "about 0.0086 near normal": BRF 0.0276..0.0290 in the file for 10 deg in, <= 30 deg out
    near = scan.brdf_per_sr[(scan.theta_i_deg == 10) & (scan.theta_r_deg <= 30)]
    assert len(near) == 10
    np.testing.assert_allclose(near, 0.027 / np.pi, rtol=0.08)


def test_forward_lobe_and_half_planes():
    scan = read_z307()
    fwd = (scan.theta_i_deg == 70) & (scan.phi_r_deg == 0)
    back = (scan.theta_i_deg == 70) & (scan.phi_r_deg == 180)
    assert fwd.sum() == 15 and back.sum() == 13  # view_a=180 rows 75..5 and 0, view_a=0 rows 5..58
    peak = scan.brdf_per_sr[fwd & (scan.theta_r_deg == 75)][0]
    spec = scan.brdf_per_sr[fwd & (scan.theta_r_deg == 70)][0]
    # PHYSICS §1: 0.48 sr^-1 at 75 deg vs 0.27 at 70 (BRF 1.521307, 0.842353)
    assert peak == pytest.approx(1.521307 / np.pi) and spec == pytest.approx(0.842353 / np.pi)
    assert scan.incidence_angles_deg.tolist() == [10.0, 30.0, 50.0, 70.0]
    assert set(scan.polarization.tolist()) == {"u"}
    assert len(scan) == 112  # 120 lines - 6 header lines - the two 0/45 reference rows
    np.testing.assert_allclose(scan.brdf_std_per_sr, 0.05 * scan.brdf_per_sr)


def test_wavelength_choice_and_other_dataset():
    scan = read_z307(dataset="12_cycle", wavelength_nm=1059)
    assert scan.wavelength_nm[0] == 1059.04
    assert scan.brdf_per_sr[(scan.theta_i_deg == 70) & (scan.theta_r_deg == 75)][0] == pytest.approx(3.201186 / np.pi)
    with pytest.raises(ValueError, match="wavelength_nm"):
        read_z307(wavelength_nm=532)


def test_preset_model_fits_the_real_data_within_the_documented_residuals():
    """docs/materials-fitting.md table: lambertian+microfacet rms log10 per angle 0.020/0.017/0.032/0.032
    (all 0.026); lambertian+k_correlation 0.053/0.050/0.099/0.238 (a beta-centred lobe cannot follow
    the grazing forward lobe). Bounds here are the documented values plus 0.005 dex."""
    from materials.fit import fit

    scan = read_z307()
    best = fit(scan, "lambertian+microfacet", seed=0, n_starts=8)
    documented = {10.0: 0.020, 30.0: 0.017, 50.0: 0.032, 70.0: 0.032}
    for (t, pol), rms in best.rms_log10.items():
        assert 0.0 < rms < documented[t] + 0.005, t
    assert best.rms_log10_total < 0.026 + 0.005
    kc = fit(scan, "lambertian+k_correlation", seed=0, n_starts=4)
    assert kc.rms_log10[(70.0, "u")] > 0.15 > best.rms_log10[(70.0, "u")]


def test_shipped_preset_reproduces_the_data_and_conserves_energy():
    import materials.microfacet  # noqa: F401  (registers the component type)
    from materials.fit import evaluate_components
    from materials.material import load_material

    mat = load_material("z307")  # load runs the rho < 1 check for s and p, 0..89 deg
    scan = read_z307()
    ratio = np.log10(evaluate_components(mat.components, scan) / scan.brdf_per_sr)
    for t in scan.incidence_angles_deg:
        m = scan.theta_i_deg == t
        assert np.sqrt(np.mean(ratio[m] ** 2)) < 0.037, t
    assert mat.wavelength_nm == 630.79 and "bsdf-tools" in mat.provenance
    rho = mat.albedo(np.radians([0.0, 45.0, 85.0]), "s")
    assert np.all((rho > 0.02) & (rho < 1.0))
