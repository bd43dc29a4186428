"""Aluminium's complex refractive index n + ik at a wavelength, for the mirrors of an imported prescription.

Data: A. D. Rakic, "Algorithm for the determination of intrinsic optical constants of metal films:
application to aluminum", Appl. Opt. 34, 4755-4767 (1995), as tabulated by the refractiveindex.info
database (public domain, CC0; file main/Al/Rakic.yml). Linear interpolation between the rows;
outside 365-1240 nm the end rows are used.
"""
from __future__ import annotations

import numpy as np

# wavelength_um, n, k  (Rakic 1995, refractiveindex.info main/Al/Rakic.yml)
_RAKIC = np.array([
    [0.36466, 0.39877, 4.3957], [0.41328, 0.52135, 5.0008], [0.44280, 0.60790, 5.3676],
    [0.47687, 0.72780, 5.7781], [0.51660, 0.87340, 6.2418], [0.56357, 1.07280, 6.7839],
    [0.61993, 1.36600, 7.4052], [0.65225, 1.57240, 7.7354], [0.68881, 1.83010, 8.0601],
    [0.72932, 2.16060, 8.3565], [0.77491, 2.61540, 8.4914], [0.79478, 2.76750, 8.3866],
    [0.81569, 2.76680, 8.2573], [0.83774, 2.69450, 8.1878], [0.88561, 2.28020, 8.1134],
    [0.91166, 1.97390, 8.3058], [0.93928, 1.67840, 8.5970], [0.96863, 1.48670, 9.0655],
    [0.99988, 1.43590, 9.4939], [1.03320, 1.39980, 9.8914],
])


def aluminium_nk(wavelength_nm: float) -> tuple[float, float]:
    """(n, k) of evaporated aluminium at ``wavelength_nm`` (Rakic 1995, interpolated)."""
    um = float(wavelength_nm) / 1000.0
    n = float(np.interp(um, _RAKIC[:, 0], _RAKIC[:, 1]))
    k = float(np.interp(um, _RAKIC[:, 0], _RAKIC[:, 2]))
    return round(n, 4), round(k, 4)
