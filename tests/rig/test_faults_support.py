"""Shared helpers for the rig scan tests (a small plan, a reference run, row comparison); no tests here."""
import numpy as np

from materials.kcorrelation import KCorrelation  # noqa: F401 - registers the component type
from materials.material import material_from_dict
from rig.plans import PlanSpec, Point, point_key
from rig.run import run_scan, sim_instrument

MATERIAL = material_from_dict({"name": "test_glossy", "wavelength_nm": 532.0, "components": [
    {"type": "lambertian", "rd": 0.03},
    {"type": "k_correlation", "sigma_nm": 3.0, "lc_um": 40.0, "s": 2.4, "n": 1.52}]})

POINTS = tuple(Point(ti, pol, tr, 0.0) for pol in ("s", "p") for ti in (30.0, 70.0)
               for tr in (ti - 5.0, ti - 0.2, ti, ti + 0.2, ti + 5.0))
SPEC = PlanSpec(name="small", points=POINTS, n_readings=3)


def instrument(seed=3):
    return sim_instrument(MATERIAL, seed=seed)


def run(devices, path, spec=SPEC, **kw):
    kw.setdefault("fsync", False)
    kw.setdefault("handle_signals", False)
    return run_scan(devices, spec, path, sample="test_glossy", **kw)


def rows(scan):
    """{point key: (brdf, std, n)} of a Scan, asserting no key appears twice."""
    keys = [point_key(*k) for k in zip(scan.theta_i_deg, scan.polarization, scan.theta_r_deg, scan.phi_r_deg)]
    assert len(keys) == len(set(keys)), "duplicate points in the CSV"
    return {k: (b, s, n) for k, b, s, n in zip(keys, scan.brdf_per_sr, scan.brdf_std_per_sr, scan.n_repeats)}


def assert_same_scan(a, b):
    """Same points, no duplicates or gaps, same values (the sim's noise is keyed by position; the
    forward model evaluated point by point or vectorised agrees to round-off, hence rtol 1e-12)."""
    ra, rb = rows(a), rows(b)
    assert set(ra) == set(rb)
    for k in ra:
        np.testing.assert_allclose(np.array(ra[k], float), np.array(rb[k], float), rtol=1e-12, err_msg=str(k))
