"""Contract tests run over every registered component type (via ``example()``), the
composite example and every preset (STYLE §2 and §7; shape of Mitsuba's per-BSDF
tests, mitsuba3 src/bsdfs/tests, and pbrt-v4 src/pbrt/bsdfs_test.cpp).

References for the expected values are never the code under test's own output:
* the scattered power sum(weight)/N of ``sample`` is compared with the quadrature of
  f cos over the beta disk (materials.albedo, itself checked against analytic values
  in test_models_albedo.py);
* the sampled-direction histogram is compared with the bin integrals of ``pdf``
  (scipy.stats.chisquare) and the weighted histogram with the bin integrals of f cos.
"""
import numpy as np
import pytest
from scipy import stats

import materials
from materials.albedo import directional_hemispherical_reflectance, pdf_integral
from materials.base import Brdf, directions_from_angles
from materials.flags import ComponentFlags
from materials.registry import component_types

SEED = 20260611
N_MC = 40_000


def _models():
    # delta components (specular, dielectric) have no finite BRDF: tests/materials/test_smooth_interfaces.py
    out = [(name, cls.example()) for name, cls in sorted(component_types().items()) if not cls.flags & ComponentFlags.DELTA]
    out.append(("composite", materials.Composite.example()))
    out += [(f"preset:{p}", materials.load_material(p)) for p in materials.list_presets()]
    return out


MODELS = _models()
IDS = [name for name, _ in MODELS]
THETAS_DEG = (10.0, 45.0, 80.0)


def _wi(theta_deg, n):
    wi, _ = directions_from_angles(np.full(n, np.deg2rad(theta_deg)), 0.0, 0.0)
    return wi


def _random_dirs(rng, n, lower=False):
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    if not lower:
        v[:, 2] = np.abs(v[:, 2])
    return v


@pytest.mark.parametrize("name,model", MODELS, ids=IDS)
def test_model_follows_protocol_and_round_trips(name, model):
    assert isinstance(model, Brdf)
    d = model.to_dict()
    assert isinstance(d, dict)
    if name.startswith("preset:") or name == "composite":
        return
    rebuilt = materials.registry.build_component(d)
    rng = np.random.default_rng(SEED)
    wi, wo = _random_dirs(rng, 200), _random_dirs(rng, 200)
    if "wavelength_nm" in {f for f in type(model).__dataclass_fields__}:
        assert rebuilt.wavelength_nm == model.wavelength_nm
    np.testing.assert_array_equal(rebuilt.brdf(wi, wo, "s"), model.brdf(wi, wo, "s"))


@pytest.mark.parametrize("name,model", MODELS, ids=IDS)
def test_brdf_is_non_negative_finite_and_zero_below_horizon(name, model):
    rng = np.random.default_rng(SEED)
    wi, wo = _random_dirs(rng, 4000, lower=True), _random_dirs(rng, 4000, lower=True)
    for pol in "spu":
        f = model.brdf(wi, wo, pol)
        assert f.shape == (4000,)
        assert np.all(np.isfinite(f)) and np.all(f >= 0)
        below = (wi[:, 2] <= 0) | (wo[:, 2] <= 0)
        assert np.all(f[below] == 0)
        assert np.any(f[~below] > 0)  # sanity: not vacuously zero


RECIPROCAL = [(name, m) for name, m in MODELS if getattr(m, "reciprocal", False)]


def test_reciprocal_flag_is_declared_by_the_physical_models():
    names = {name for name, _ in RECIPROCAL}
    assert {"lambertian", "k_correlation", "composite", "preset:z302_sample_a"} <= names


@pytest.mark.parametrize("name,model", RECIPROCAL, ids=[n for n, _ in RECIPROCAL])
def test_reciprocity_for_physical_models(name, model):
    """f(wi -> wo) == f(wo -> wi) for unpolarized incidence (PHYSICS §2), arbitrary azimuths.
    Models that are not reciprocal by construction (tabulated) set ``reciprocal = False``."""
    rng = np.random.default_rng(SEED + 1)
    wi, wo = _random_dirs(rng, 3000), _random_dirs(rng, 3000)
    a = model.brdf(wi, wo, "u")
    b = model.brdf(wo, wi, "u")
    assert np.all(a > 0)
    np.testing.assert_allclose(a, b, rtol=1e-10, atol=0)


@pytest.mark.parametrize("name,model", MODELS, ids=IDS)
def test_identical_uniforms_give_identical_draws_whatever_the_batch(name, model):
    rng = np.random.default_rng(SEED)
    n = 2000
    wi = _random_dirs(rng, n)
    u = rng.random((n, 3))
    s1 = model.sample(wi, u, "s")
    s2 = model.sample(wi.copy(), u.copy(), "s")
    parts = [model.sample(wi[i : i + 300], u[i : i + 300], "s") for i in range(0, n, 300)]
    for field in ("wo", "weight", "pdf_per_sr"):
        np.testing.assert_array_equal(getattr(s1, field), getattr(s2, field))
        np.testing.assert_array_equal(getattr(s1, field), np.concatenate([getattr(p, field) for p in parts]))
    assert np.all(s1.weight >= 0) and np.all(np.isfinite(s1.weight))
    np.testing.assert_allclose(np.linalg.norm(s1.wo, axis=1), 1.0, atol=1e-12)


@pytest.mark.parametrize("theta_deg", THETAS_DEG)
@pytest.mark.parametrize("name,model", MODELS, ids=IDS)
def test_pdf_integrates_to_the_above_horizon_fraction(name, model, theta_deg):
    """Integral of pdf over the hemisphere <= 1 and equals the fraction of draws above the horizon."""
    integral = float(pdf_integral(model, np.deg2rad(theta_deg), "s"))
    rng = np.random.default_rng([SEED, int(theta_deg)])
    s = model.sample(_wi(theta_deg, N_MC), rng.random((N_MC, 3)), "s")
    frac = np.mean(s.wo[:, 2] > 0)
    se = np.sqrt(max(frac * (1 - frac), 1.0 / N_MC) / N_MC)  # binomial standard error
    assert 0 < integral <= 1 + 1e-6
    assert abs(integral - frac) < 4 * se + 1e-4, (integral, frac, se)


@pytest.mark.parametrize("pol", ["s", "p"])
@pytest.mark.parametrize("theta_deg", THETAS_DEG)
@pytest.mark.parametrize("name,model", MODELS, ids=IDS)
def test_monte_carlo_scattered_power_matches_quadrature(name, model, theta_deg, pol):
    """mean(weight) estimates rho = integral f cos dOmega (PHYSICS §3).

    Tolerance: 4 standard errors of the run itself (fixed seed; 4 rather than 3 because
    ~90 comparisons run here) plus 2e-5 relative for the quadrature (its accuracy is
    checked in test_models_albedo.py), which matters only for exact samplers whose
    weight is constant.
    """
    rho = float(directional_hemispherical_reflectance(model, np.deg2rad(theta_deg), pol))
    rng = np.random.default_rng([SEED, int(theta_deg), ord(pol)])
    s = model.sample(_wi(theta_deg, N_MC), rng.random((N_MC, 3)), pol)
    mean = s.weight.mean()
    se = s.weight.std(ddof=1) / np.sqrt(N_MC)
    assert rho > 0 and mean > 0
    assert abs(mean - rho) <= 4 * se + 2e-5 * rho, (mean, rho, se)


# ----------------------------------------------------------------------------- chi-square


def _bins(theta_deg):
    """Polar bins about beta0: log-spaced radii (resolves 1e-4-wide lobes) x 6 azimuth sectors."""
    r_edges = np.concatenate([[0.0], np.logspace(-5, np.log10(2.0), 61)])
    psi_edges = np.linspace(0, 2 * np.pi, 7)
    return r_edges, psi_edges


def _bin_integrals(func, theta_deg, r_edges, psi_edges, n_r=16, n_psi=48):
    """Integral of func(wi, wo) d^2beta over each (r, psi) bin clipped to the unit disk.

    Gauss-Legendre in r on [r_lo, min(r_hi, r_edge(psi))] (squeezed to the upper end),
    midpoint in psi.
    """
    b = np.sin(np.deg2rad(theta_deg))
    xg, wg = np.polynomial.legendre.leggauss(n_r)
    nb_r, nb_p = len(r_edges) - 1, len(psi_edges) - 1
    psi = (
        psi_edges[:-1, None] + (np.arange(n_psi)[None, :] + 0.5) / n_psi * np.diff(psi_edges)[:, None]
    )  # (nb_p, n_psi)
    dpsi = (np.diff(psi_edges) / n_psi)[:, None]
    r_edge = -b * np.cos(psi) + np.sqrt(1 - (b * np.sin(psi)) ** 2)
    lo = np.minimum(r_edges[:-1, None, None], r_edge[None])  # (nb_r, nb_p, n_psi)
    hi = np.minimum(r_edges[1:, None, None], r_edge[None])
    span = (hi - lo)[..., None]
    tt = 0.5 * (xg + 1)
    # nodes squeezed toward the upper end, where a bin may touch the disk edge and a
    # density per beta can diverge as 1 / cos(theta_r) (integrable)
    r = lo[..., None] + span * (1 - (1 - tt) ** 2)  # (nb_r, nb_p, n_psi, n_r)
    w = span * (1 - tt) * wg * r * dpsi[None, :, :, None]
    c, s = np.cos(psi)[None, :, :, None], np.sin(psi)[None, :, :, None]
    bx = (b + r * c).ravel()
    by = np.broadcast_to(r * s, r.shape).ravel()
    bz = np.sqrt(np.maximum(1 - bx**2 - by**2, 0))
    wo = np.stack([bx, by, bz], axis=-1)
    wi = _wi(theta_deg, len(wo))
    vals = func(wi, wo).reshape(r.shape)
    return np.sum(vals * w, axis=(2, 3))  # (nb_r, nb_p)


def _bin_index(wo, theta_deg, r_edges, psi_edges):
    b = np.sin(np.deg2rad(theta_deg))
    dx, dy = wo[:, 0] - b, wo[:, 1]
    r = np.hypot(dx, dy)
    psi = np.mod(np.arctan2(dy, dx), 2 * np.pi)
    ir = np.clip(np.searchsorted(r_edges, r, side="right") - 1, 0, len(r_edges) - 2)
    ip = np.clip(np.searchsorted(psi_edges, psi, side="right") - 1, 0, len(psi_edges) - 2)
    return ir * (len(psi_edges) - 1) + ip


def _merge_small(expected, observed, minimum=20.0):
    """Pool bins (in order of expectation) until each pooled bin expects >= minimum counts."""
    order = np.argsort(expected)
    e_out, o_out, e_acc, o_acc = [], [], 0.0, 0.0
    for k in order:
        e_acc += expected[k]
        o_acc += observed[k]
        if e_acc >= minimum:
            e_out.append(e_acc)
            o_out.append(o_acc)
            e_acc = o_acc = 0.0
    if e_acc > 0:
        e_out[-1] += e_acc
        o_out[-1] += o_acc
    return np.array(e_out), np.array(o_out)


@pytest.mark.parametrize("theta_deg", THETAS_DEG)
@pytest.mark.parametrize("name,model", MODELS, ids=IDS)
def test_chi_square_of_sampled_directions(name, model, theta_deg):
    """Counts of draws per beta bin vs N x integral of pdf per bin (+ a below-horizon bin),
    scipy.stats.chisquare p > 1e-3 (fixed seed); and the weighted histogram vs the bin
    integrals of f cos, with a chi-square built from the per-bin standard errors."""
    pol = "s"
    r_edges, psi_edges = _bins(theta_deg)
    rng = np.random.default_rng([SEED, 7, int(theta_deg)])
    s = model.sample(_wi(theta_deg, N_MC), rng.random((N_MC, 3)), pol)
    above = s.wo[:, 2] > 0
    idx = _bin_index(s.wo[above], theta_deg, r_edges, psi_edges)
    nbins = (len(r_edges) - 1) * (len(psi_edges) - 1)

    def per_beta_pdf(wi, wo):
        c = wo[:, 2]
        return np.where(c > 0, model.pdf(wi, wo, pol) / np.where(c > 0, c, 1), 0.0)

    p_bins = _bin_integrals(per_beta_pdf, theta_deg, r_edges, psi_edges).ravel()
    assert 0.5 < p_bins.sum() <= 1 + 1e-6  # sanity: the bins hold the density
    observed = np.bincount(idx, minlength=nbins).astype(float)
    expected = N_MC * p_bins
    observed = np.append(observed, N_MC - above.sum())
    expected = np.append(expected, N_MC * max(1 - p_bins.sum(), 0.0))
    e, o = _merge_small(expected, observed)
    e *= o.sum() / e.sum()  # chisquare needs equal totals; the pdf-integral test checks the total
    assert len(e) >= 10
    p_value = stats.chisquare(o, e).pvalue
    assert p_value > 1e-3, p_value

    # weighted histogram against f cos: sum of weights per bin / N estimates its integral
    f_bins = _bin_integrals(lambda wi, wo: model.brdf(wi, wo, pol), theta_deg, r_edges, psi_edges).ravel()
    w = s.weight[above]
    sums = np.bincount(idx, weights=w, minlength=nbins) / N_MC
    sq = np.bincount(idx, weights=w * w, minlength=nbins) / N_MC
    var = np.maximum(sq - sums**2, 0) / N_MC
    counts = np.bincount(idx, minlength=nbins)
    use = counts >= 30
    assert f_bins[use].sum() > 0.5 * f_bins.sum() > 0
    stat = np.sum((sums[use] - f_bins[use]) ** 2 / np.maximum(var[use], 1e-300))
    dof = int(use.sum())
    assert stats.chi2.sf(stat, dof) > 1e-3, (stat, dof)
