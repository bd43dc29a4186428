"""Pieces of the diagnosis (rig.diagnose) that do not need a full fit."""
import numpy as np
import pytest

from materials.fresnel import polarization_factor
from materials.kcorrelation import KCorrelation
from materials.scan import make_scan
from rig.diagnose import (DiagnoseError, FitMaterial, Problem, classify_regions, default_holdout,
                          q_factor_real)
from rig.forward import predict_brdf


def test_regions_by_angle_from_specular():
    ti = np.full(8, 30.0)
    tr = np.array([30.0, 30.4, 31.0, 34.9, 50.0, 80.0, -25.0, -60.0])
    got = classify_regions(ti, tr).tolist()
    assert got == ["specular_core", "specular_core", "shoulder", "shoulder", "wing", "grazing", "near_retro", "wing"]


def test_real_q_factor_matches_materials_fresnel():
    """The fit's real-arithmetic Q (PHYSICS §1) equals materials.fresnel.polarization_factor."""
    rng = np.random.default_rng(3)
    ci, cr = rng.uniform(0.05, 1.0, 500), rng.uniform(0.05, 1.0, 500)
    phi = rng.uniform(0, 2 * np.pi, 500)
    for pol in "spu":
        a = q_factor_real(ci, cr, np.cos(phi), np.sin(phi), 1.52, pol)
        b = polarization_factor(ci, cr, np.cos(phi), np.sin(phi), complex(1.52), pol)
        np.testing.assert_allclose(a, b, rtol=1e-10)


def test_fit_material_equals_kcorrelation_components():
    """FitMaterial (cached-geometry path) reads like the materials package's own models."""
    fm = FitMaterial(0.02, ((3.0, 20.0, 2.4), (20.0, 1.0, 3.0)), 1.5, 532.0)
    comps = [KCorrelation(sigma_nm=3.0, lc_um=20.0, s=2.4, n=1.5, wavelength_nm=532.0),
             KCorrelation(sigma_nm=20.0, lc_um=1.0, s=3.0, n=1.5, wavelength_nm=532.0)]

    class Ref:
        def brdf(self, wi, wo, pol="u"):
            return 0.02 / np.pi * ((wi[:, 2] > 0) & (wo[:, 2] > 0)) + sum(c.brdf(wi, wo, pol) for c in comps)

    tr = np.array([-70.0, 0.0, 29.0, 30.0, 30.1, 60.0])
    for pol in "sp":
        np.testing.assert_allclose(predict_brdf(fm, 30.0, tr, 0.0, pol), predict_brdf(Ref(), 30.0, tr, 0.0, pol), rtol=1e-10)


def test_default_holdout_is_middle_and_highest():
    assert default_holdout([10, 25, 40, 55, 70, 80]) == [40.0, 80.0]
    assert default_holdout([10, 30, 40, 70, 80]) == [40.0, 80.0]
    assert default_holdout([10, 30, 50, 70]) == [30.0, 70.0]
    assert default_holdout([10, 70]) == [70.0]
    assert default_holdout([45]) == []


def _scan(y, std, ti=(10.0, 30.0, 50.0)):
    n = len(y)
    return make_scan(wavelength_nm=532.0, polarization="s", theta_i_deg=np.resize(np.array(ti), n),
                     theta_r_deg=np.linspace(0, 60, n), brdf_per_sr=y, brdf_std_per_sr=std, n_repeats=3)


def test_points_below_their_own_noise_are_not_used():
    """Usable: brdf > 2 x std / sqrt(n); NaN and negative readings kept in the file but unused."""
    y = np.array([1.0, 1e-3, -1e-4, np.nan] + [0.5] * 20)
    std = np.array([0.05, 2e-3, 1e-4, 0.1] + [0.02] * 20)
    p = Problem(_scan(y, std), holdout_theta_i_deg=[50.0])
    # 1e-3 with std 2e-3: sem 1.15e-3 -> 1e-3 < 2.3e-3, below its noise
    assert p.usable[:4].tolist() == [True, False, False, False]
    assert p.usable[4:].all()


def test_bad_holdout_is_a_clear_error():
    y = np.full(30, 0.1)
    with pytest.raises(DiagnoseError, match="--holdout-theta-i 45: no such incidence angle"):
        Problem(_scan(y, y * 0.05), holdout_theta_i_deg=[45.0])


def test_executor_gives_the_serial_results():
    """Independent fits on a caller-owned ProcessPoolExecutor give the serial loop's results."""
    from concurrent.futures import ProcessPoolExecutor

    from rig.diagnose import fit_baseline, fit_many
    from rig.points import compact_plan
    from rig.synth import glossy_black, synth_scan

    scan = synth_scan(glossy_black(), compact_plan(theta_i_deg=(10.0, 40.0, 70.0), polarizations=("s",)), [],
                      seed=3, n_samples=256)
    p = Problem(scan)
    names = ["angle_offset", "stray_background"]
    serial = fit_baseline(p)
    a = fit_many(p, serial, names)
    with ProcessPoolExecutor(max_workers=2) as pool:
        pooled = fit_baseline(p, pool)
        b = fit_many(p, serial, names, pool)
    assert pooled.chi2 == serial.chi2 and pooled.model.values == serial.model.values
    assert [a[n].chi2 for n in names] == [b[n].chi2 for n in names]