"""A scan point and its identity: the key a CSV row, a plan and ``--resume`` agree on."""
from __future__ import annotations

from typing import NamedTuple


class Point(NamedTuple):
    theta_i_deg: float
    polarization: str
    theta_r_deg: float
    phi_r_deg: float = 0.0


def point_key(theta_i_deg, polarization, theta_r_deg, phi_r_deg) -> tuple:
    """Hashable identity of a point, angles rounded to 1e-6 deg (resume matches on it)."""
    return (round(float(theta_i_deg), 6), str(polarization), round(float(theta_r_deg), 6),
            round(float(phi_r_deg) % 360.0, 6))
