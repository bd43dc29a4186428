"""Effective emissivity of an isothermal, diffuse, grey cylindrical cavity (radius R, depth L,
closed flat bottom, open top) by the net-radiation (radiosity) method: the integral equation of
Sparrow, Albers & Eckert (J. Heat Transfer 84, 73 (1962); Sparrow & Cess, *Radiation Heat
Transfer*, ch. 7) discretised into wall bands and bottom annuli whose exchange factors are exact,
from the coaxial-disk view factor (PHYSICS §5) by view-factor algebra. Deterministic and
independent of the tracer: it is the reference of test_benchmark_cavity.py.

Exchange (A_i F_ij) between wall bands [a, b] and [c, d] (b <= c), with S(x, y) = pi R^2
F_disk(R, R, |x - y|): S(b, c) - S(b, d) - S(a, c) + S(a, d) (the radiation from below b that
reaches [c, d] crosses the disk at b as from a black disk, minus what the disk at a sends).
"""
import numpy as np


def disk_f(r1, r2, h):
    """Coaxial parallel disks r1 -> r2 at distance h (PHYSICS §5); h = 0: min(1, (r2/r1)^2)."""
    if h <= 0:
        return min(1.0, (r2 / r1) ** 2)
    R1, R2 = r1 / h, r2 / h
    X = 1 + (1 + R2 ** 2) / R1 ** 2
    return (X - np.sqrt(X ** 2 - 4 * (R2 / R1) ** 2)) / 2


def effective_emissivity(eps_wall, radius, depth, n_wall=200, n_bottom=40):
    """Hemispherical effective emissivity of the opening: power out / (pi R^2 E_b)."""
    R, L = float(radius), float(depth)
    # bands denser toward the opening, where the radiosity changes fastest
    z = L * (1 - (1 - np.linspace(0, 1, n_wall + 1)) ** 1.5)
    r = R * np.sqrt(np.linspace(0, 1, n_bottom + 1))

    def S(x, y):
        return np.pi * R * R * disk_f(R, R, abs(x - y))

    def X(ra, h):  # exchange disk of radius ra at the bottom -> disk R at height h
        return np.pi * ra * ra * disk_f(ra, R, h) if ra > 0 else 0.0

    n = n_wall + n_bottom
    area = np.zeros(n)
    G = np.zeros((n, n))  # exchange A_i F_ij
    out = np.zeros(n)  # exchange with the opening
    for k in range(n_wall):
        a, b = z[k], z[k + 1]
        area[k] = 2 * np.pi * R * (b - a)
        for m in range(k + 1, n_wall):
            c, d = z[m], z[m + 1]
            G[k, m] = G[m, k] = S(b, c) - S(b, d) - S(a, c) + S(a, d)
        G[k, k] = area[k] - 2 * (np.pi * R * R - S(a, b))
        out[k] = S(b, L) - S(a, L)
    for j in range(n_bottom):
        i = n_wall + j
        r1, r2 = r[j], r[j + 1]
        area[i] = np.pi * (r2 ** 2 - r1 ** 2)
        for k in range(n_wall):
            g = (X(r2, z[k]) - X(r1, z[k])) - (X(r2, z[k + 1]) - X(r1, z[k + 1]))
            G[i, k] = G[k, i] = g
        out[i] = X(r2, L) - X(r1, L)
    F = G / area[:, None]
    rho = 1.0 - eps_wall
    J = np.linalg.solve(np.eye(n) - rho * F, np.full(n, eps_wall))
    return float(out @ J / (np.pi * R * R))
