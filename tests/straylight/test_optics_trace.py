"""The Fresnel surface response (``optical_surface.OpticalSurface``) in the tracer: windows, Brewster's angle, polarization, focus.

References (independent of the code under test):
- incoherent multiple reflections in a plane-parallel plate (Born & Wolf §7.6.1; Hecht §9.7):
  T = (1 - R) / (1 + R), R_plate = 2R / (1 + R) per polarization, R from Fresnel; unpolarized light
  transmits the mean of the s and p series, not the series of the mean R;
- Brewster's angle tan(theta_B) = n: p light is not reflected (outside, and inside at the refracted angle);
- a paraboloid sends every ray parallel to its axis through its focus (Born & Wolf §4.10).
Monte Carlo tolerances: 4 standard errors of the run (fixed seeds).
"""
import math

import numpy as np
import pytest

from geometry import Scene
from geometry.analytic import Conic, Plane, analytic_part
from materials import load_material
from straylight.polarization import SourcePolarization, attach
from straylight.sources import CollimatedDisk
from straylight.trace import EstimatorOptions, TraceOptions, trace

N_GLASS = 1.5
GLASS = load_material({"name": "glass", "components": [{"type": "dielectric", "n": N_GLASS}]})
UP = np.array([0.0, 0.0, 1.0])


def _plate_scene(radius=300.0):
    top = analytic_part("top", Plane(np.array([0, 0, 10.0]), UP, math.inf, 0.0, radius, 0.0), "glass")
    bottom = analytic_part("bottom", Plane(np.zeros(3), -UP, math.inf, 0.0, radius, 0.0), "glass")
    det = analytic_part("det", Plane(np.array([0, 0, -20.0]), UP, math.inf, 0.0, 3 * radius, 0.0), None, "detector")
    return Scene((top, bottom, det))


def _beam(theta_deg, pol=None):
    a = math.radians(theta_deg)
    src = CollimatedDisk(center_mm=np.array([-60 * math.tan(a), 0, 60.0]), normal=np.array([0, 0, -1.0]),
                         direction=np.array([math.sin(a), 0, -math.cos(a)]), radius_mm=5.0)
    if pol is not None:  # e_field: s = along y (normal to the plane of incidence xz), p = in the plane
        e = np.array([0.0, 1.0, 0.0]) if pol == "s" else np.array([math.cos(a), 0.0, math.sin(a)])
        attach(src, SourcePolarization("linear", tuple(e)))
    return src


def _fresnel(theta, n=N_GLASS):
    c = math.cos(theta)
    q = math.sqrt(n * n - math.sin(theta) ** 2)
    return ((c - q) / (c + q)) ** 2, ((n * n * c - q) / (n * n * c + q)) ** 2


def _run(theta_deg, pol=None, n=400_000, seed=1):
    res = trace(_plate_scene(), [_beam(theta_deg, pol)], n, seed=seed, materials={"glass": GLASS},
                options=TraceOptions(estimator=EstimatorOptions(nee=False)))
    absorbed = sum(t.power_w for t in res.absorbed.values())
    balance = res.emitted_w - res.detectors["det"].power_w - res.escaped.power_w - absorbed
    assert abs(balance) < 1e-9 * res.emitted_w  # power balance
    return res.detectors["det"], res.escaped


def test_window_at_normal_incidence_transmits_the_incoherent_series():
    R = ((N_GLASS - 1) / (N_GLASS + 1)) ** 2
    det, esc = _run(0.0)
    assert abs(det.power_w - (1 - R) / (1 + R)) < 4 * det.stderr_w
    assert abs(esc.power_w - 2 * R / (1 + R)) < 4 * esc.stderr_w


def test_window_at_45_deg_transmits_the_mean_of_the_s_and_p_series():
    Rs, Rp = _fresnel(math.radians(45))
    expected = 0.5 * ((1 - Rs) / (1 + Rs) + (1 - Rp) / (1 + Rp))
    wrong = (1 - 0.5 * (Rs + Rp)) / (1 + 0.5 * (Rs + Rp))  # the series of the mean reflectance
    det, _ = _run(45.0)
    assert abs(det.power_w - expected) < 4 * det.stderr_w
    assert abs(det.power_w - wrong) > 4 * det.stderr_w  # the test can tell the two apart
    # unpolarized = the mean of two orthogonal linear polarizations traced separately
    ds, _ = _run(45.0, "s", seed=2)
    dp, _ = _run(45.0, "p", seed=3)
    assert abs(ds.power_w - (1 - Rs) / (1 + Rs)) < 4 * ds.stderr_w
    assert abs(dp.power_w - (1 - Rp) / (1 + Rp)) < 4 * dp.stderr_w
    err = math.sqrt(det.stderr_w**2 + 0.25 * (ds.stderr_w**2 + dp.stderr_w**2))
    assert abs(det.power_w - 0.5 * (ds.power_w + dp.power_w)) < 4 * err


def test_brewster_angle_reflects_no_p():
    theta_b = math.degrees(math.atan(N_GLASS))
    det, esc = _run(theta_b, "p", n=50_000)
    assert esc.power_w == 0.0 and det.power_w == pytest.approx(1.0, abs=1e-12)
    Rs, _ = _fresnel(math.radians(theta_b))
    det_s, esc_s = _run(theta_b, "s", n=200_000)
    assert esc_s.power_w > 0.1 and abs(esc_s.power_w - 2 * Rs / (1 + Rs)) < 4 * esc_s.stderr_w


def test_bulk_absorption_of_a_thick_window():
    """absorption_per_mm = 0.05 over 10 mm at normal incidence: the incoherent series with the
    internal transmittance tau = exp(-0.5): T = (1-R)^2 tau / (1 - R^2 tau^2)."""
    glass = load_material({"name": "glass", "components": [{"type": "dielectric", "n": N_GLASS,
                                                            "absorption_per_mm": 0.05}]})
    res = trace(_plate_scene(), [_beam(0.0)], 300_000, seed=4, materials={"glass": glass},
                options=TraceOptions(estimator=EstimatorOptions(nee=False)))
    R = ((N_GLASS - 1) / (N_GLASS + 1)) ** 2
    tau = math.exp(-0.5)
    det = res.detectors["det"]
    assert abs(det.power_w - (1 - R) ** 2 * tau / (1 - R**2 * tau**2)) < 4 * det.stderr_w


def test_paraboloid_focuses_on_a_0p02_mm_detector():
    """Mirror r = 0.9 (constant), R = 2000 mm, k = -1, aperture 20..100 mm: a collimated on-axis
    disk of radius 99 mm; the 0.02-mm detector at the focus gets 0.9 x the power on the mirror
    (the annulus 20..99 of the uniform disk, (99^2 - 20^2) / 99^2 of the beam)."""
    mirror = load_material({"name": "m", "components": [{"type": "specular", "r": 0.9}]})
    prim = analytic_part("primary", Conic(np.zeros(3), UP, 2000.0, -1.0, 100.0, 20.0), "m", tolerance_mm=0.05)
    det = analytic_part("focus", Plane(np.array([0, 0, 1000.0]), -UP, math.inf, 0.0, 0.02, 0.0), None, "detector")
    src = CollimatedDisk(center_mm=np.array([0, 0, 1500.0]), normal=-UP, direction=-UP, radius_mm=99.0)
    n = 200_000
    res = trace(Scene((prim, det)), [src], n, seed=5, materials={"m": mirror}, options=TraceOptions(estimator=EstimatorOptions(nee=False)))
    frac = (99.0**2 - 20.0**2) / 99.0**2
    got = res.detectors["focus"]
    err = 0.9 * math.sqrt(frac * (1 - frac) / n)  # binomial: which rays meet the mirror
    assert got.power_w > 0.5 and abs(got.power_w - 0.9 * frac) < 4 * err


def test_window_from_a_closed_cad_mesh():
    """A dielectric on a closed mesh (no prescription: facet normals; the medium is inside): the
    same incoherent series at normal incidence as the analytic window."""
    import trimesh

    from geometry.mesh import Part

    box = trimesh.creation.box([200.0, 200.0, 10.0])
    box.apply_translation((0, 0, 5.0))
    slab = Part("slab", np.asarray(box.vertices), np.asarray(box.faces), "glass")
    det = analytic_part("det", Plane(np.array([0, 0, -20.0]), UP, math.inf, 0.0, 900.0, 0.0), None, "detector")
    res = trace(Scene((slab, det)), [_beam(0.0)], 200_000, seed=6, materials={"glass": GLASS},
                options=TraceOptions(estimator=EstimatorOptions(nee=False)))
    R = ((N_GLASS - 1) / (N_GLASS + 1)) ** 2
    got = res.detectors["det"]
    assert abs(got.power_w - (1 - R) / (1 + R)) < 4 * got.stderr_w
