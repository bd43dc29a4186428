"""Thin-film coatings (CONTRACTS 5.1 ``coating``, materials/thin_film.py) against an independent
interface/propagation transfer-matrix reference (Byrnes, "Multilayer optical calculations",
arXiv:1603.02720, eqs. 1-15), written here from the textbook formulas."""
import numpy as np
import pytest

from materials.fresnel import fresnel_amplitudes
from materials.material import load_material
from materials.base import MaterialError
from materials.smooth import Dielectric, Specular
from materials.thin_film import NAMED_DESIGNS

NS = 1.5168


def tmm_reference(pol, ns, ds, th0, lam):
    """Byrnes' tmm (coh_tmm): interface matrices (1/t)[[1, r], [r, 1]] and propagation
    diag(exp(-i delta), exp(i delta)); R = |r|^2, T = Re(n_f cos_f)/Re(n_0 cos_0) |t|^2 (s),
    Re(n_f conj(cos_f))/Re(n_0 conj(cos_0)) |t|^2 (p)."""
    ns = np.asarray(ns, complex)
    s0 = ns[0] * np.sin(th0)
    cos = np.sqrt(1 - (s0 / ns) ** 2 + 0j)
    q = ns * cos
    cos = np.where(q.imag < 0, -cos, cos)
    def rt(i, j):
        if pol == "s":
            a, b = ns[i] * cos[i], ns[j] * cos[j]
            return (a - b) / (a + b), 2 * a / (a + b)
        a, b = ns[j] * cos[i], ns[i] * cos[j]
        return (a - b) / (a + b), 2 * ns[i] * cos[i] / (a + b)
    r, t = rt(0, 1)
    M = np.array([[1, r], [r, 1]], complex) / t
    for i in range(1, len(ns) - 1):
        delta = 2 * np.pi * ns[i] * cos[i] * ds[i] / lam
        P = np.array([[np.exp(-1j * delta), 0], [0, np.exp(1j * delta)]])
        r, t = rt(i, i + 1)
        M = M @ P @ (np.array([[1, r], [r, 1]], complex) / t)
    rr, tt = M[1, 0] / M[0, 0], 1 / M[0, 0]
    if pol == "s":
        T = abs(tt) ** 2 * (ns[-1] * cos[-1]).real / (ns[0] * cos[0]).real
    else:
        T = abs(tt) ** 2 * (ns[-1] * np.conj(cos[-1])).real / (ns[0] * np.conj(cos[0])).real
    return abs(rr) ** 2, T


def test_zero_thickness_is_bare_fresnel():
    c = np.cos(np.radians([0, 20, 45, 70, 89]))
    bare = Dielectric(n=NS).coefficients(c)
    film = Dielectric(n=NS, coating=[{"n": 1.38, "thickness_nm": 0.0}], wavelength_nm=500.0).coefficients(c)
    assert np.allclose(film.r_s, bare.r_s) and np.allclose(film.r_p, bare.r_p)
    assert np.allclose(film.T_s, bare.T_s) and np.allclose(film.T_p, bare.T_p)
    m = Specular(n=(0.96, 6.69), coating=[{"n": 1.46, "thickness_nm": 0.0}], wavelength_nm=532.0)
    rs, rp, *_ = fresnel_amplitudes(c, complex(0.96, 6.69))
    assert np.allclose(m.coefficients(c).r_s, rs) and np.allclose(m.coefficients(c).r_p, rp)


@pytest.mark.parametrize("design", ["broadband_ar", "mgf2_quarter_wave"])
@pytest.mark.parametrize("theta_deg", [0.0, 45.0, 70.0])
def test_s_and_p_against_tmm_reference(design, theta_deg):
    lam = 600.0
    d = Dielectric(n=NS, coating=design, wavelength_nm=lam)
    co = d.coefficients(np.array([np.cos(np.radians(theta_deg))]))
    layers = [(complex(n, k), w * lam / n) for n, k, w in NAMED_DESIGNS[design]]
    ns = [1.0] + [n for n, _ in layers] + [NS]
    ds = [0.0] + [t for _, t in layers] + [0.0]
    for pol, R, T in (("s", co.R_s[0], co.T_s[0]), ("p", co.R_p[0], co.T_p[0])):
        Rr, Tr = tmm_reference(pol, ns, ds, np.radians(theta_deg), lam)
        assert R == pytest.approx(Rr, rel=1e-9, abs=1e-12)
        assert T == pytest.approx(Tr, rel=1e-9)
        assert R + T == pytest.approx(1.0, abs=1e-12)


def test_absorbing_stack_energy_and_reference():
    layers = [(complex(2.0, 0.3), 40.0), (complex(1.38, 0.0), 90.0), (complex(0.5, 2.5), 8.0)]
    th = np.radians(np.array([0.0, 30.0, 60.0]))
    d = Dielectric(n=NS, wavelength_nm=550.0,
                   coating=[{"n": [n.real, n.imag], "thickness_nm": t} for n, t in layers])
    co = d.coefficients(np.cos(th))
    Rs, Rp, Ts, Tp = co.R_s, co.R_p, co.T_s, co.T_p
    As, Ap = 1 - Rs - Ts, 1 - Rp - Tp
    assert np.all(As > 0) and np.all(Ap > 0)
    assert np.allclose(Rs + Ts + As, 1.0) and np.allclose(Rp + Tp + Ap, 1.0)
    ns = [1.0] + [n for n, _ in layers] + [NS]
    ds = [0.0] + [t for _, t in layers] + [0.0]
    for i, t in enumerate(th):
        for pol, R, T in (("s", Rs[i], Ts[i]), ("p", Rp[i], Tp[i])):
            Rr, Tr = tmm_reference(pol, ns, ds, t, 550.0)
            assert R == pytest.approx(Rr, rel=1e-8)
            assert T == pytest.approx(Tr, rel=1e-8)


def test_protected_aluminium_and_material_file():
    m = load_material({"name": "al", "wavelength_nm": 532.0, "components": [
        {"type": "specular", "n": [0.96, 6.69], "coating": "protected_aluminium"}]})
    R = m.smooth.coefficients(np.array([1.0])).R_s[0]
    bare = abs((1 - complex(0.96, 6.69)) / (1 + complex(0.96, 6.69))) ** 2
    assert R == pytest.approx(bare, rel=1e-9)  # a half-wave overcoat is absent at normal incidence
    c = np.cos(np.radians(50.0))
    assert m.smooth.coefficients(np.array([c])).R_p[0] != pytest.approx(
        Specular(n=(0.96, 6.69)).coefficients(np.array([c])).R_p[0], rel=1e-5)
    with pytest.raises(MaterialError):
        load_material({"name": "x", "wavelength_nm": 532.0, "components": [
            {"type": "dielectric", "n": 1.5, "coating": "no_such_design"}]})

