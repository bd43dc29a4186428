"""Polarization through mirrors and scattering parts (CONTRACTS §6.3).

References, all independent of the code under test:
- Fresnel reflection of a metal (Born & Wolf §14.2; Chipman, Lam & Young, *Polarized Light and
  Optical Systems* ch. 8): r_s = (cos - q)/(cos + q), r_p = (N^2 cos - q)/(N^2 cos + q),
  q = sqrt(N^2 - sin^2), written out here; Abeles' relation r_p = r_s^2 at 45 deg (any N;
  F. Abeles, C. R. Acad. Sci. 230, 1942 (1950); Azzam & Bashara, *Ellipsometry*, §4.3);
  aluminium at 532 nm, N = 0.96 + 6.69i (Rakic 1995 via refractiveindex.info), reflects about
  92 % at normal incidence (Bennett & Bennett; Bass, *Handbook of Optics* II, ch. 35: ~91.6 %
  at 500-550 nm for fresh evaporated Al).
- An ideal (perfectly conducting) mirror turns the field into E' = -E + 2 (E . n) n (tangential
  part reversed; Jackson §8.1).
- Malus's law behind a Brewster-angle reflector (it reflects s only: p reflectance 0 at
  tan theta_B = n): P = R_s(theta_B) cos^2(angle between the field and s).
- Rayleigh-Rice s and p BRDF of the K-correlation lobe: NIST SCATMECH golden values of
  /work/shared/reference/PHYSICS.md §1 (lambda 0.532 um, n 1.5, sigma 10 nm, Lc 2 um, s 2.6,
  plus Lambertian 0.03).
Monte Carlo tolerances: 4 standard errors of the run (fixed seeds) plus a stated model error.
"""
import math

import numpy as np
import pytest

from geometry import Scene
from geometry.analytic import Plane, analytic_part
from materials import load_material
from materials.mueller import interface_mueller
from materials.smooth import Specular
from straylight.polarization import SourcePolarization, attach
from straylight.sources import CollimatedDisk
from straylight.trace import EstimatorOptions, OutputOptions, PhysicsOptions, TraceOptions, trace

AL_532 = complex(0.96, 6.69)
N_GLASS = 1.5
THETA_B = math.atan(N_GLASS)
GLASS = load_material({"name": "glass", "components": [{"type": "dielectric", "n": N_GLASS}]})
ALUMINIUM = load_material({"name": "al", "components": [{"type": "specular", "n": [0.96, 6.69]}]})


def _textbook_r(theta, N):
    c, s2 = math.cos(theta), math.sin(theta) ** 2
    q = np.sqrt(N * N - s2 + 0j)
    return (c - q) / (c + q), (N * N * c - q) / (N * N * c + q)


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


# ------------------------------------------------------------------ Mueller matrices, no tracing


def test_aluminium_mirror_mueller_matches_the_textbook_fresnel_formula():
    theta = math.radians(45.0)
    rs, rp = _textbook_r(theta, AL_532)
    Rs, Rp = abs(rs) ** 2, abs(rp) ** 2
    assert math.isclose(Rp, Rs**2, rel_tol=1e-12)  # Abeles at 45 deg
    assert 0.88 < Rp < Rs < 0.96  # 0.891 and 0.944
    r0s, _ = _textbook_r(0.0, AL_532)
    assert abs(abs(r0s) ** 2 - 0.92) < 0.01  # published ~92 % at normal incidence
    coef = Specular(n=(0.96, 6.69)).coefficients(np.array([math.cos(theta)]))
    M = interface_mueller(coef.r_s, coef.r_p)[0]
    c = rs * np.conj(rp)
    want = np.array([[(Rs + Rp) / 2, (Rs - Rp) / 2, 0, 0], [(Rs - Rp) / 2, (Rs + Rp) / 2, 0, 0],
                     [0, 0, c.real, c.imag], [0, 0, -c.imag, c.real]])
    np.testing.assert_allclose(M, want, atol=1e-14)
    # a metal mirror is a retarder: 45-deg linear light comes back elliptical, fully polarized
    S = M @ np.array([1.0, 0.0, 1.0, 0.0])
    assert abs(S[3]) > 0.05 * S[0]
    assert math.isclose(float(np.linalg.norm(S[1:])), S[0], rel_tol=1e-12)


# ------------------------------------------------------------------ traced mirrors and analysers


def _beam(direction, e_field=None, center=(0.0, 0.0, 100.0), radius=2.0):
    d = _unit(direction)
    src = CollimatedDisk(center_mm=np.asarray(center, float), normal=d, direction=d, radius_mm=radius)
    if e_field is not None:
        attach(src, SourcePolarization("linear", tuple(_unit(e_field))))
    return src


def _detector_after(point, direction, name="det", distance=100.0, radius=20.0):
    p = np.asarray(point, float) + distance * _unit(direction)
    return analytic_part(name, Plane(p, -_unit(direction), math.inf, 0.0, radius, 0.0), None, "detector")


def _fold(mirror_kind, analyser_gamma_deg):
    """Beam along -z onto a 45-deg fold at the origin (normal (1,0,1)/sqrt 2: reflected along +x),
    then a Brewster-angle glass analyser at x = 60 whose plane of incidence is turned by gamma about
    x (its s vector is cos(gamma) z - sin(gamma) y), then a detector on the analyser's reflection."""
    n_m = _unit([1.0, 0.0, 1.0])
    if mirror_kind == "role":
        fold = analytic_part("fold", Plane(np.zeros(3), n_m, math.inf, 0.0, 15.0, 0.0), None, "mirror")
    else:
        fold = analytic_part("fold", Plane(np.zeros(3), n_m, math.inf, 0.0, 15.0, 0.0), "al")
    g = math.radians(analyser_gamma_deg)
    n_a = _unit(-math.cos(THETA_B) * np.array([1.0, 0, 0])
                + math.sin(THETA_B) * np.array([0.0, math.cos(g), math.sin(g)]))
    p_a = np.array([60.0, 0.0, 0.0])
    analyser = analytic_part("analyser", Plane(p_a, n_a, math.inf, 0.0, 15.0, 0.0), "glass")
    d2 = np.array([1.0, 0, 0]) - 2 * np.dot([1.0, 0, 0], n_a) * n_a
    s_a = np.array([0.0, -math.sin(g), math.cos(g)])
    return Scene((fold, analyser, _detector_after(p_a, d2))), s_a


def _fold_power(mirror_kind, e_field, gamma_deg, n=100_000, seed=3, mirror_r=1.0):
    scene, s_a = _fold(mirror_kind, gamma_deg)
    res = trace(scene, [_beam([0, 0, -1], e_field)], n, seed=seed, materials={"glass": GLASS, "al": ALUMINIUM},
                options=TraceOptions(estimator=EstimatorOptions(nee=False), physics=PhysicsOptions(mirror_reflectance=mirror_r)))
    t = res.detectors["det"]
    return t.power_w / res.emitted_w, t.stderr_w / res.emitted_w, s_a


def _rs_brewster():
    return abs(_textbook_r(THETA_B, N_GLASS)[0]) ** 2


@pytest.mark.parametrize("a_deg,gamma_deg", [(0.0, 0.0), (30.0, 0.0), (90.0, 0.0), (20.0, 65.0)])
def test_malus_law_through_a_role_mirror_and_a_brewster_analyser(a_deg, gamma_deg):
    """Linear light, field e0 = (cos a, sin a, 0), off an ideal role-mirror fold (R = 0.9) into a Brewster
    analyser: P / P0 = 0.9 R_s(theta_B) (E' . s_a)^2 with E' = -e0 + 2 (e0 . n) n. Before the
    mirror kept the polarization it depolarized the light and every case read 0.45 R_s(theta_B)."""
    a = math.radians(a_deg)
    e0 = np.array([math.cos(a), math.sin(a), 0.0])
    n_m = _unit([1.0, 0.0, 1.0])
    e1 = -e0 + 2 * np.dot(e0, n_m) * n_m
    got, err, s_a = _fold_power("role", e0, gamma_deg, mirror_r=0.9)
    want = 0.9 * _rs_brewster() * np.dot(e1, s_a) ** 2
    assert abs(got - want) <= 4 * err + 1e-12, (got, want, err)


@pytest.mark.parametrize("a_deg,gamma_deg", [(45.0, 0.0), (45.0, 45.0), (45.0, -45.0), (30.0, 80.0)])
def test_a_metal_fold_keeps_its_retardance_up_to_the_analyser(a_deg, gamma_deg):
    """The same fold in aluminium (a Fresnel surface): the reflected field is r_s E_s s + r_p E_p p_out
    (Jones calculus, s = d x n, p = d x s on both sides; checked here against the conductor limit),
    and the Brewster analyser reads R_s(theta_B) |E . s_a|^2: the relative phase of r_s and r_p
    (S2 -> S3 in Mueller form) changes the reading at gamma = +-45 deg."""
    a = math.radians(a_deg)
    e0 = np.array([math.cos(a), math.sin(a), 0.0])
    d0, d1 = np.array([0.0, 0, -1]), np.array([1.0, 0, 0])
    n_m = _unit([1.0, 0.0, 1.0])
    s_m = _unit(np.cross(d0, n_m))
    p_in, p_out = np.cross(d0, s_m), np.cross(d1, s_m)

    def jones_out(rs, rp):
        return rs * np.dot(e0, s_m) * s_m + rp * np.dot(e0, p_in) * p_out

    np.testing.assert_allclose(jones_out(-1.0, 1.0), -e0 + 2 * np.dot(e0, n_m) * n_m, atol=1e-15)
    rs, rp = _textbook_r(math.radians(45.0), AL_532)
    got, err, s_a = _fold_power("metal", e0, gamma_deg)
    want = _rs_brewster() * abs(np.dot(jones_out(rs, rp), s_a)) ** 2
    assert abs(got - want) <= 4 * err + 1e-12, (got, want, err)


@pytest.mark.parametrize("pol", ["s", "p", "u"])
def test_aluminium_mirror_reflects_rs_rp_and_their_mean(pol):
    """A flat aluminium mirror at 45 deg: the detector gets exactly R_s, R_p or (R_s + R_p)/2 of the
    beam (a mirror has one outcome, so the weights are deterministic)."""
    n_m = _unit([1.0, 0.0, 1.0])
    mirror = analytic_part("m", Plane(np.zeros(3), n_m, math.inf, 0.0, 15.0, 0.0), "al")
    e = {"s": [0.0, 1.0, 0.0], "p": [1.0, 0.0, 0.0], "u": None}[pol]
    res = trace(Scene((mirror, _detector_after(np.zeros(3), [1.0, 0, 0]))), [_beam([0, 0, -1], e)], 2000, seed=1,
                materials={"al": ALUMINIUM}, options=TraceOptions(estimator=EstimatorOptions(nee=False)))
    rs, rp = _textbook_r(math.radians(45.0), AL_532)
    want = {"s": abs(rs) ** 2, "p": abs(rp) ** 2, "u": (abs(rs) ** 2 + abs(rp) ** 2) / 2}[pol]
    assert math.isclose(res.detectors["det"].power_w / res.emitted_w, want, rel_tol=1e-12)


# ------------------------------------------------------------------ scatter with s and p light

# SCATMECH goldens (PHYSICS §1): theta_i, theta_r (deg), f_s, f_p (1/sr), in the plane of incidence
SCATMECH = [(45.0, 55.0, 2.02963e-02, 9.89642e-03), (10.0, 20.0, 1.32037e-02, 1.26139e-02),
            (80.0, 82.0, 5.69068e-02, 3.23008e-02)]
SAMPLE = load_material({"name": "rr_sample", "wavelength_nm": 532.0, "components": [
    {"type": "lambertian", "rd": 0.03}, {"type": "k_correlation", "sigma_nm": 10.0, "lc_um": 2.0, "s": 2.6, "n": 1.5}]})
ARM_MM, DET_R_MM = 200.0, 1.0


def _scatter_reading(theta_i_deg, theta_r_deg, pol, n=4000, seed=5, option="u"):
    """Detector power / (P_in Omega cos theta_r) for a flat sample at the origin (normal +z), a beam
    in the xz plane and a 1 mm disk detector at 200 mm toward theta_r on the specular side."""
    ti, tr = math.radians(theta_i_deg), math.radians(theta_r_deg)
    d = np.array([math.sin(ti), 0.0, -math.cos(ti)])
    e = {"s": [0.0, 1.0, 0.0], "p": [math.cos(ti), 0.0, math.sin(ti)], "u": None}[pol]
    sample = analytic_part("sample", Plane(np.zeros(3), np.array([0, 0, 1.0]), math.inf, 0.0, 30.0, 0.0), "rr")
    out = np.array([math.sin(tr), 0.0, math.cos(tr)])
    det = _detector_after(np.zeros(3), out, distance=ARM_MM, radius=DET_R_MM)
    res = trace(Scene((sample, det)), [_beam(d, e, center=-80 * d, radius=0.3)], n, seed=seed,
                materials={"rr": SAMPLE}, options=TraceOptions(output=OutputOptions(detector_sides="front"), physics=PhysicsOptions(polarization=option)))
    area = math.pi * DET_R_MM**2  # an analytic detector disk is traced exactly (CONTRACTS 6.4)
    omega = area / ARM_MM**2
    scale = 1.0 / (res.emitted_w * omega * math.cos(tr))
    t = res.detectors["det"]
    return t.power_w * scale, t.stderr_w * scale


@pytest.mark.parametrize("theta_i,theta_r,f_s,f_p", SCATMECH)
def test_s_and_p_light_scatter_as_the_rayleigh_rice_s_and_p_brdf(theta_i, theta_r, f_s, f_p):
    """Linearly polarized sources (s: field along y; p: in the plane of incidence) on a rough
    dielectric sample read the SCATMECH s and p BRDFs; unpolarized light reads their mean. The
    detector (0.29 deg half-angle) and the footprint smear the lobe by < 0.5 % (0.3 % at 80 deg)."""
    got = {pol: _scatter_reading(theta_i, theta_r, pol) for pol in ("s", "p", "u")}
    for pol, want in (("s", f_s), ("p", f_p), ("u", 0.5 * (f_s + f_p))):
        value, err = got[pol]
        assert abs(value - want) <= 4 * err + 0.005 * want, (pol, value, want, err)
    assert f_s != pytest.approx(f_p, rel=0.02) or theta_i < 20  # the cases tell s from p where they should


def test_a_linear_source_scatters_as_the_global_s_option():
    """Per-ray s light and the trace-wide ``polarization = "s"`` option (the twin's mode) agree."""
    a, ea = _scatter_reading(45.0, 55.0, "s")
    b, eb = _scatter_reading(45.0, 55.0, "u", option="s")
    assert abs(a - b) <= 4 * math.hypot(ea, eb) + 1e-12 * b


# ------------------------------------------------------------------ light polarized by scatter


def _analysed_scatter(orientation, n=60_000, seed=11, scatter_polarization="on"):
    """Unpolarized beam at 45 deg on the rough sample; a 1 mm Brewster analyser 100 mm away toward
    theta_r = 55 deg (in the plane of incidence) reflects the s part of the scattered light onto a
    detector; a baffle hides the detector from the sample. ``orientation``: "perp" (the analyser's
    s normal to the plane of incidence) or "in_plane". Returns P/P0, stderr and the expected
    0.5 R_s(theta_B) cos(theta_r) Omega_proj per unit BRDF."""
    ti, tr = math.radians(45.0), math.radians(55.0)
    d = np.array([math.sin(ti), 0.0, -math.cos(ti)])
    u = np.array([math.sin(tr), 0.0, math.cos(tr)])
    w = np.array([math.cos(tr), 0.0, -math.sin(tr)]) if orientation == "perp" else np.array([0.0, 1.0, 0.0])
    n_a = -math.cos(THETA_B) * u + math.sin(THETA_B) * w
    A = 100.0 * u
    analyser = analytic_part("analyser", Plane(A, n_a, math.inf, 0.0, 1.0, 0.0), "glass")
    d2 = u - 2 * np.dot(u, n_a) * n_a
    D = A + 30.0 * d2
    det = analytic_part("det", Plane(D, -d2, math.inf, 0.0, 3.0, 0.0), None, "detector")
    baffle = analytic_part("baffle", Plane(0.5 * D, _unit(D), math.inf, 0.0, 6.0, 0.0), None, "absorber")
    sample = analytic_part("sample", Plane(np.zeros(3), np.array([0, 0, 1.0]), math.inf, 0.0, 30.0, 0.0), "rr")
    res = trace(Scene((sample, analyser, det, baffle)), [_beam(d, None, center=-80 * d, radius=0.3)], n, seed=seed,
                materials={"rr": SAMPLE, "glass": GLASS},
                options=TraceOptions(estimator=EstimatorOptions(nee=False, target_parts=("analyser",), rr_threshold=0.0), output=OutputOptions(detector_sides="front"), physics=PhysicsOptions(scatter_polarization=scatter_polarization)))
    area = math.pi * 1.0**2  # the analytic 1 mm analyser disk, traced exactly (CONTRACTS 6.4)
    per_brdf = 0.5 * _rs_brewster() * math.cos(tr) * area * math.cos(THETA_B) / 100.0**2
    t = res.detectors["det"]
    return t.power_w / res.emitted_w, t.stderr_w / res.emitted_w, per_brdf


def test_scattered_light_carries_the_rayleigh_rice_polarization():
    """Rough glass polarizes what it scatters: in the plane of incidence the scattered s and p
    intensities of unpolarized light are f_s/2 and f_p/2 (Q_ss, Q_pp; no cross terms), so a Brewster
    analyser reads R_s f_s/2 or R_s f_p/2 per unit projected solid angle, SCATMECH's f_s/f_p = 2.05 at
    45/55 deg apart (a depolarizing scatter would read (f_s + f_p)/4 for both). 2 % for the lobe's
    and R_s's variation over the 1 mm analyser."""
    perp, e_perp, k = _analysed_scatter("perp")
    par, e_par, _ = _analysed_scatter("in_plane")
    f_s, f_p = SCATMECH[0][2], SCATMECH[0][3]
    assert abs(perp - k * f_s) <= 4 * e_perp + 0.02 * k * f_s, (perp, k * f_s, e_perp)
    assert abs(par - k * f_p) <= 4 * e_par + 0.02 * k * f_p, (par, k * f_p, e_par)


def test_default_scatter_drops_the_polarization_it_creates_from_unpolarized_light():
    """``scatter_polarization = "auto"`` (default): unpolarized light leaves the rough sample
    unpolarized, so both analyser orientations read k (f_s + f_p) / 2, the mean of the two "on"
    readings (same tolerance as above)."""
    perp, e_perp, k = _analysed_scatter("perp", scatter_polarization="auto")
    par, e_par, _ = _analysed_scatter("in_plane", scatter_polarization="auto")
    mean = 0.5 * k * (SCATMECH[0][2] + SCATMECH[0][3])
    for got, err in ((perp, e_perp), (par, e_par)):
        assert abs(got - mean) <= 4 * err + 0.02 * mean, (got, mean, err)


def test_second_vertex_sampling_stays_out_of_polarized_traces():
    from straylight.engine.second_vertex import unsupported
    from straylight.trace import make_spec

    sample = analytic_part("sample", Plane(np.zeros(3), np.array([0, 0, 1.0]), math.inf, 0.0, 30.0, 0.0), "rr")
    det = analytic_part("det", Plane(np.array([0, 0, 50.0]), np.array([0, 0, -1.0]), math.inf, 0.0, 3.0, 0.0), None,
                        "detector")
    beam = [_beam(np.array([0, 0, -1.0]), None, center=np.array([0, 0, 80.0]), radius=0.3)]

    def why(**physics):
        return unsupported(make_spec(Scene((sample, det)), beam, 10, 1, {"rr": SAMPLE},
                                     TraceOptions(physics=PhysicsOptions(**physics))))

    assert why() is None
    assert "polarized" in why(scatter_polarization="on")


def test_scatter_polarization_option_is_checked():
    with pytest.raises(ValueError, match="scatter_polarization"):
        TraceOptions(physics=PhysicsOptions(scatter_polarization="yes"))


# ------------------------------------------------------------------ the engine goldens

# tests/data/engine_golden/tube_mixed_seed3.json (default scatter_polarization = "auto": unpolarized
# light leaves scatter unpolarized): (power_w, stderr_w). With "on", its "glossy" vanes (k_correlation,
# n = 1.5) polarize what they scatter, which changes the numbers; they must agree within the error.
PRE_POLARIZATION_TUBE_MIXED = {
    "detector": (0.07522096299981577, 0.0016258619324287366), "wall": (0.35575769991468054, 0.0029984409514318775),
    "vane_1": (0.20657246629063594, 0.002509222391377084), "vane_2": (0.14668685007652235, 0.0021760448993799583),
    "vane_3": (0.1742588763065237, 0.0023049379610122385), "vane_4": (0.17155468694121614, 0.002308170986215482),
    "vane_5": (0.17228293106556442, 0.002297416599308157), "vane_6": (0.1503041242563965, 0.002197197902711544),
    "vane_7": (0.036553958549327685, 0.0011171869680024153)}


def test_golden_tube_with_polarizing_vanes_agrees_with_its_unpolarized_record(tmp_path):
    """Following the polarization that scatter creates changes the numbers (not bit-identical to the
    golden), within the error."""
    import json
    from pathlib import Path

    from straylight.cli.main import main

    golden = Path(__file__).resolve().parents[1] / "data" / "engine_golden"
    out = tmp_path / "t.json"
    assert main(["trace", str(golden / "tube_mixed.toml"), "--rays", "40000", "--seed", "3", "--json", str(out),
                 "--scatter-polarization", "on"]) == 0
    doc = json.loads(out.read_text())
    got = {"detector": doc["detectors"]["detector"]["power_w"], **{k: v["power_w"] for k, v in doc["absorbed"].items()}}
    assert got["detector"] != PRE_POLARIZATION_TUBE_MIXED["detector"][0]  # the option took effect
    for name, (old, err) in PRE_POLARIZATION_TUBE_MIXED.items():
        assert abs(got[name] - old) <= 3 * err, (name, got[name], old, err)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_out_of_plane_scatter_reads_s2_through_the_cross_terms(sign):
    """Linear light at +-45 deg between s and p, 45 deg in, 30 deg out at 30 deg azimuth: the reading
    is |J E|^2 of the Rayleigh-Rice Jones matrix (materials.rayleigh_rice, checked against Germer and
    Fresnel in tests/materials/test_rayleigh_rice_mueller.py) scaled to the lobe's unpolarized BRDF,
    plus the Lambertian part. The lobe reads about twice as much at -45 as at +45 deg here (M02 S2);
    with the Lambertian part the readings differ by 2.3 %, some 700 standard errors, where s/p
    factors alone would read the same. Agreement is within 1e-5; 0.1 % allowed."""
    from materials.rayleigh_rice import rayleigh_rice_jones

    ti, tr, ph = math.radians(45.0), math.radians(30.0), math.radians(30.0)
    d = np.array([math.sin(ti), 0.0, -math.cos(ti)])
    s = _unit(np.cross(d, [0.0, 0.0, 1.0]))
    p = np.cross(d, s)
    e = (s + sign * p) / math.sqrt(2)
    out = np.array([math.sin(tr) * math.cos(ph), math.sin(tr) * math.sin(ph), math.cos(tr)])
    sample = analytic_part("sample", Plane(np.zeros(3), np.array([0, 0, 1.0]), math.inf, 0.0, 30.0, 0.0), "rr")
    det = _detector_after(np.zeros(3), out, distance=ARM_MM, radius=DET_R_MM)
    res = trace(Scene((sample, det)), [_beam(d, e, center=-80 * d, radius=0.3)], 4000, seed=9,
                materials={"rr": SAMPLE}, options=TraceOptions(output=OutputOptions(detector_sides="front")))
    area = math.pi * DET_R_MM**2  # an analytic detector disk is traced exactly (CONTRACTS 6.4)
    scale = 1.0 / (res.emitted_w * area / ARM_MM**2 * math.cos(tr))
    got, err = res.detectors["det"].power_w * scale, res.detectors["det"].stderr_w * scale
    wi, wo = -d[None, :], out[None, :]
    J, _ = rayleigh_rice_jones(wi, wo, 1.5, s_in=s[None, :])
    E = np.array([1.0, sign]) / math.sqrt(2)
    lam, lobe = SAMPLE.components
    f_lobe = lobe.brdf(wi, wo, "u")[0] * np.sum(np.abs(J[0] @ E) ** 2) / (0.5 * np.sum(np.abs(J[0]) ** 2))
    want = f_lobe + lam.brdf(wi, wo, "u")[0]
    assert abs(got - want) <= 4 * err + 0.001 * want, (got, want, err)


def test_compiled_scattered_rows_are_the_numpy_formulas():
    """Arriving.scattered's compiled pass after the Mueller BRDFs (the states M S, the weight ratios, the frame
    vectors) gives its numpy twin's bits: random matrices and states, polarized and unpolarized arrivals,
    M00 zero, negative and NaN, (M S)_0 <= 0, gathered and scattered rows, a one-row and an empty batch."""
    from straylight.engine.interactions.scatter_polarization import scattered_rows, scattered_rows_numpy

    rng = np.random.default_rng(8)
    n_all, n_out = 5000, 3000
    S = np.column_stack([np.ones(n_all), rng.uniform(-1, 1, (n_all, 3)) / 2])
    polarized = rng.uniform(size=n_all) < 0.7
    tangent, bitangent, nf = (rng.normal(size=(n_all, 3)) for _ in range(3))
    for m in (2000, 1, 0):
        M = rng.normal(size=(m, 4, 4)) * np.exp(rng.normal(size=(m, 4, 4)))
        M[:10, 0, 0] = [0.0, -0.0, -1.0, np.nan, 1e-300, 0.0, 2.0, -3.0, np.nan, 1.0][:min(m, 10)]
        e1_loc = rng.normal(size=(m, 3))
        at = rng.integers(0, n_all, m)
        to = rng.permutation(n_out)[:m]
        g = rng.permutation(n_all)[:m]
        outs = []
        for fn in (scattered_rows, scattered_rows_numpy):
            ratio, S_out, e1 = np.full(n_out, 7.0), np.full((n_all, 4), 7.0), np.full((n_all, 3), 7.0)
            fn(M, e1_loc, S, polarized, tangent, bitangent, nf, at, to, g, ratio, S_out, e1)
            outs.append((ratio, S_out, e1))
        for got, want in zip(*outs):
            np.testing.assert_array_equal(got, want)
            assert np.array_equal(np.signbit(got), np.signbit(want))
    assert (outs[0][1] == 7.0).all()  # the empty batch wrote nothing
