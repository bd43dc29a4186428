"""The twin's half-wave plate and polarizing beam-splitter as Mueller elements (rig/beam_optics.py).

Independent references:
- Jones calculus (Hecht, *Optics* §8.13; Chipman et al. ch. 5): a half-wave plate with its fast
  axis at theta is R(-theta) diag(1, -1) R(theta); an ideal PBS port is the projector onto its
  axis (p: transmitted, s: reflected); the Stokes vector of a field (E1, E2) is
  (|E1|^2 + |E2|^2, |E1|^2 - |E2|^2, 2 Re E1 E2*, 2 Im E1* E2).
- Malus-like behind the PBS: s light through the HWP at theta leaves at 2 theta, so the s port
  passes cos^2(2 theta) and the p port sin^2(2 theta) of it.
- The material's own s and p BRDFs through the fast model (rig.forward.predict_brdf, quadrature
  over slit and beam, 0.3 %): what the twin reads with the HWP/PBS selecting s or p.
"""
import math

import numpy as np
import pytest

from materials import load_material
from rig.beam_optics import (BeamOptics, BeamOpticsError, HalfWavePlate, PolarizingBeamSplitter, beam_parts)
from rig.forward import predict_brdf
from rig.twin import TwinConfig, TwinError, twin_point


def _stokes(E):
    E1, E2 = E
    return np.array([abs(E1) ** 2 + abs(E2) ** 2, abs(E1) ** 2 - abs(E2) ** 2, 2 * (E1 * np.conj(E2)).real,
                     2 * (np.conj(E1) * E2).imag])


def _rot(t):
    return np.array([[math.cos(t), math.sin(t)], [-math.sin(t), math.cos(t)]])


@pytest.mark.parametrize("theta_deg", [0.0, 10.0, 22.5, 37.0, 45.0, 80.0])
@pytest.mark.parametrize("E", [(1.0, 0.0), (0.6, 0.8j), (math.sqrt(0.5), -math.sqrt(0.5))])
def test_hwp_and_pbs_mueller_match_jones_calculus(theta_deg, E):
    t = math.radians(theta_deg)
    E = np.array(E, complex)
    J_hwp = _rot(-t) @ np.diag([1.0, -1.0]) @ _rot(t)
    np.testing.assert_allclose(HalfWavePlate(theta_deg).mueller() @ _stokes(E), _stokes(J_hwp @ E), atol=1e-12)
    for port, J in (("transmitted", np.diag([0.0, 1.0])), ("reflected", np.diag([1.0, 0.0]))):
        np.testing.assert_allclose(PolarizingBeamSplitter(port).mueller() @ _stokes(E), _stokes(J @ E), atol=1e-12)
    # a leaky cube (extinction 100) lets 1 % of the blocked power through
    leak = PolarizingBeamSplitter("transmitted", extinction=100.0).mueller() @ _stokes(np.array([1.0, 0.0]))
    assert leak[0] == pytest.approx(0.01)


@pytest.mark.parametrize("theta_deg", [0.0, 15.0, 22.5, 30.0, 45.0])
def test_malus_like_power_behind_the_pbs(theta_deg):
    t = math.radians(theta_deg)
    s_port = BeamOptics((HalfWavePlate(theta_deg), PolarizingBeamSplitter("reflected"))).stokes()
    p_port = BeamOptics((HalfWavePlate(theta_deg), PolarizingBeamSplitter("transmitted"))).stokes()
    assert s_port[0] == pytest.approx(math.cos(2 * t) ** 2, abs=1e-12)
    assert p_port[0] == pytest.approx(math.sin(2 * t) ** 2, abs=1e-12)
    assert beam_parts(s_port)[-1][1] == pytest.approx((0.0, 1.0, 0.0)) if s_port[0] > 0 else True  # s = y
    # the seed paper's order (PBS, then the HWP): s at 0 deg, p at 45 deg, full power both
    S = BeamOptics((PolarizingBeamSplitter("reflected"), HalfWavePlate(theta_deg))).stokes()
    assert S[0] == pytest.approx(1.0) and S[1] == pytest.approx(math.cos(4 * t), abs=1e-12)


def test_bad_optics_are_named():
    with pytest.raises(BeamOpticsError, match="port"):
        PolarizingBeamSplitter("sideways")
    with pytest.raises(BeamOpticsError, match="laser_stokes"):
        BeamOptics((), laser_stokes=(1.0, 2.0, 0.0, 0.0))
    with pytest.raises(BeamOpticsError, match="elliptical"):
        beam_parts(BeamOptics((HalfWavePlate(22.5, retardance_deg=90.0),)).stokes())
    with pytest.raises(TwinError, match="optics"):
        twin_point(load_material("z302_sample_a"), 30.0, 40.0, polarization="s", optics=BeamOptics(), n_rays=10)


MATERIAL = load_material("z302_sample_a")
NEE = TwinConfig(estimator="nee")


def test_twin_scan_over_the_hwp_angle_follows_malus_and_the_s_and_p_brdf():
    """Laser s -> HWP(theta) -> PBS port -> sample (30 deg in, 40 deg out, a wing point): the detected
    power per laser watt is cos^2(2 theta) x (s reading) on the s port and sin^2(2 theta) x (p reading)
    on the p port, and the readings normalised to the power on the sample are the fast model's s and
    p BRDF (3 sigma (+) its 0.3 %)."""
    ti, tr = 30.0, 40.0
    points = {}
    for port in ("reflected", "transmitted"):
        for th in (0.0, 22.5, 45.0, 60.0):
            if (port, th) in (("reflected", 45.0), ("transmitted", 0.0)):
                continue  # crossed: nothing reaches the sample
            optics = BeamOptics((HalfWavePlate(th), PolarizingBeamSplitter(port)))
            points[port, th] = twin_point(MATERIAL, ti, tr, twin=NEE, n_rays=6000, seed=3, optics=optics)
    f_s, f_p = (float(predict_brdf(MATERIAL, ti, tr, 0.0, pol)) for pol in ("s", "p"))
    assert f_s > 1.05 * f_p  # s and p differ here
    for (port, th), p in points.items():
        want = f_s if port == "reflected" else f_p
        assert abs(p.brdf_per_sr - want) < 3 * math.hypot(p.stderr_per_sr, 0.003 * want), (port, th, p.brdf_per_sr, want)
        malus = math.cos(math.radians(2 * th)) ** 2 if port == "reflected" else math.sin(math.radians(2 * th)) ** 2
        assert p.incident_w == pytest.approx(malus, abs=1e-12)
    # detected power vs HWP angle: Malus-like, on the same random stream (correlated errors)
    full = points["reflected", 0.0].detector_w
    assert points["reflected", 22.5].detector_w == pytest.approx(0.5 * full, rel=1e-9)
    assert points["reflected", 60.0].detector_w == pytest.approx(0.25 * full, rel=1e-9)
    # the optics' s beam reads what the trace-wide s option reads (the twin's other mode)
    s_mode = twin_point(MATERIAL, ti, tr, polarization="s", twin=NEE, n_rays=6000, seed=3)
    assert abs(points["reflected", 0.0].brdf_per_sr - s_mode.brdf_per_sr) < 3 * math.hypot(
        points["reflected", 0.0].stderr_per_sr, s_mode.stderr_per_sr)
