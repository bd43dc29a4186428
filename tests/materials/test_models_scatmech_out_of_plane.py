'''K-correlation with a refractive index against NIST SCATMECH out of the plane of incidence,
for a real and an absorbing substrate (PHYSICS §1: Germer, Appl. Opt. 36, 8798 (1997)).

The golden values below were produced by NIST SCATMECH (pySCATMECH 0.1.10, public domain) with
the script in ``GENERATOR`` (run once, outside the test suite: building pySCATMECH takes tens of
minutes, so it is not a dependency). Lobe: lambda 0.532 um, sigma 0.010 um, Lc 2.0 um, s = C = 2.6.
'''
import math

import numpy as np
import pytest

from materials import KCorrelation
from materials.base import directions_from_angles

GENERATOR = """
import math
import numpy as np
from pySCATMECH.brdf import BRDF_Model

lam, sigma, lc, C = 0.532, 0.010, 2.0, 2.6
B = 2 * math.pi * lc
A = sigma**2 * B**2 * (C - 2) / (2 * math.pi * (1 - (1 + (B / lam) ** 2) ** (1 - C / 2)))
for sub in (1.5, complex(1.6, 0.3)):
    m = BRDF_Model("Microroughness_BRDF_Model", wavelength=lam, substrate=sub, psd="ABC_PSD_Function",
                   **{"psd.A": A, "psd.B": B, "psd.C": C})
    for ti, tr, pr in ((10, 20, 5), (45, 30, 30), (45, 60, 90), (80, 70, 150), (30, 40, 180), (60, 10, 120)):
        M = np.array(m.MuellerBRDF(math.radians(ti), math.radians(tr), math.radians(pr)))
        print(sub, ti, tr, pr, M[0] @ [1, 1, 0, 0], M[0] @ [1, -1, 0, 0])  # s-, p-incident, no analyser
"""

# substrate n (or n + ik), theta_i, theta_r, phi_r (deg), f_s, f_p (1/sr)
GOLDEN = [
    (1.5, 10, 20, 5, 3.583360385e-03, 3.008545562e-03),
    (1.5, 45, 30, 30, 5.328021828e-04, 1.979774137e-04),
    (1.5, 45, 60, 90, 2.556611914e-05, 4.257300923e-05),
    (1.5, 80, 70, 150, 4.280983181e-06, 2.185513366e-05),
    (1.5, 30, 40, 180, 2.938024603e-05, 4.468876209e-05),
    (1.5, 60, 10, 120, 4.315586455e-05, 4.270006798e-05),
    (complex(1.6, 0.3), 10, 20, 5, 5.827830144e-03, 4.993168786e-03),
    (complex(1.6, 0.3), 45, 30, 30, 8.269085610e-04, 3.504480180e-04),
    (complex(1.6, 0.3), 45, 60, 90, 4.292671637e-05, 6.612072301e-05),
    (complex(1.6, 0.3), 80, 70, 150, 5.348492402e-06, 3.506294724e-05),
    (complex(1.6, 0.3), 30, 40, 180, 4.570649828e-05, 7.554520331e-05),
    (complex(1.6, 0.3), 60, 10, 120, 6.464442041e-05, 7.420679555e-05),
]


@pytest.mark.parametrize("n", [1.5, complex(1.6, 0.3)], ids=["n1.5", "n1.6+0.3i"])
def test_out_of_plane_rayleigh_rice_matches_scatmech(n):
    rows = np.array([r[1:] for r in GOLDEN if r[0] == n], float)
    index = [n.real, n.imag] if isinstance(n, complex) else n
    lobe = KCorrelation(sigma_nm=10.0, lc_um=2.0, s=2.6, n=index, wavelength_nm=532.0)
    wi, wo = directions_from_angles(np.deg2rad(rows[:, 0]), np.deg2rad(rows[:, 1]), np.deg2rad(rows[:, 2]))
    np.testing.assert_allclose(lobe.brdf(wi, wo, "s"), rows[:, 3], rtol=1e-8)
    np.testing.assert_allclose(lobe.brdf(wi, wo, "p"), rows[:, 4], rtol=1e-8)
    assert math.isclose(float(np.mean(lobe.brdf(wi, wo, "u") / (rows[:, 3] + rows[:, 4]))), 0.5, rel_tol=1e-8)


# The s = 2 branch: same lobe with C = 2 and A = sigma^2 B^2 / (pi ln(1 + (B/lambda)^2)) passed to
# SCATMECH (GENERATOR with C = 2.0 and that A, n = 1.5): theta_i, theta_r, phi_r, f_s, f_p
GOLDEN_S2 = [
    (10, 10, 0, 6.328873157e-02, 5.829362540e-02),
    (45, 47, 0, 5.437400609e-02, 4.188144752e-03),
    (45, 30, 30, 8.811706367e-04, 3.274233653e-04),
    (80, 70, 150, 1.855111151e-05, 9.470652053e-05),
]


def test_s_equal_2_branch_matches_scatmech():
    rows = np.array(GOLDEN_S2, float)
    lobe = KCorrelation(sigma_nm=10.0, lc_um=2.0, s=2.0, n=1.5, wavelength_nm=532.0)
    wi, wo = directions_from_angles(np.deg2rad(rows[:, 0]), np.deg2rad(rows[:, 1]), np.deg2rad(rows[:, 2]))
    np.testing.assert_allclose(lobe.brdf(wi, wo, "s"), rows[:, 3], rtol=1e-8)
    np.testing.assert_allclose(lobe.brdf(wi, wo, "p"), rows[:, 4], rtol=1e-8)
