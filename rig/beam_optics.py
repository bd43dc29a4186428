"""The reflectometer's polarization optics as Mueller elements: half-wave plate (HWP) and
polarizing beam-splitter cube (PBS) between the laser and the sample (seed paper §2; PHYSICS §4:
"half-wave plate + polarizing beam-splitter cube select s or p").

Frame: the laser travels along -z (rig.twin), the plane of incidence is xz, so
e1 = s = +y (normal to the plane of incidence) and e2 = d x e1 = +x (p, in the plane);
Stokes vectors as :mod:`materials.mueller` (S1 > 0: s). Angles from e1 toward e2.

Elements (Chipman, Lam & Young, *Polarized Light and Optical Systems* (2018) ch. 6;
Goldstein, *Polarized Light* (3rd ed.) §5):

- linear retarder, fast axis at theta, retardance delta (a half-wave plate: delta = 180 deg)::

      [[1, 0, 0, 0],
       [0, c^2 + s^2 cos d, c s (1 - cos d), -s sin d],
       [0, c s (1 - cos d), s^2 + c^2 cos d, c sin d],
       [0, s sin d, -c sin d, cos d]],   c = cos 2 theta, s = sin 2 theta;

  for delta = 180 deg a linear input at angle a leaves at 2 theta - a (Malus-like cos^2(2 theta)
  behind a fixed analyser);
- PBS port: a linear diattenuator along p (transmitted port) or s (reflected port) with
  power transmittances ``t_pass`` and ``t_block`` (extinction ratio t_pass / t_block; ideal: 1, 0).

The twin (:func:`rig.twin.twin_point` with ``optics=``) applies them to the laser's Stokes vector
and traces the result: a fully polarized linear beam as a linear source, a partially polarized
one as its unpolarized and linear parts traced apart.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

PORTS = ("transmitted", "reflected")


class BeamOpticsError(ValueError):
    """Bad polarization optics; the message names the parameter."""


def retarder_mueller(theta_rad: float, delta_rad: float) -> np.ndarray:
    c, s = math.cos(2 * theta_rad), math.sin(2 * theta_rad)
    cd, sd = math.cos(delta_rad), math.sin(delta_rad)
    return np.array([[1.0, 0.0, 0.0, 0.0],
                     [0.0, c * c + s * s * cd, c * s * (1 - cd), -s * sd],
                     [0.0, c * s * (1 - cd), s * s + c * c * cd, c * sd],
                     [0.0, s * sd, -c * sd, cd]])


def diattenuator_mueller(axis_rad: float, t_pass: float, t_block: float) -> np.ndarray:
    """Linear diattenuator with its pass axis at ``axis_rad`` from e1."""
    a, b = t_pass + t_block, t_pass - t_block
    g = 2.0 * math.sqrt(t_pass * t_block)
    m0 = 0.5 * np.array([[a, b, 0, 0], [b, a, 0, 0], [0, 0, g, 0], [0, 0, 0, g]])
    c, s = math.cos(2 * axis_rad), math.sin(2 * axis_rad)
    rot = np.array([[1, 0, 0, 0], [0, c, s, 0], [0, -s, c, 0], [0, 0, 0, 1.0]])  # into the axis frame
    return rot.T @ m0 @ rot


@dataclass(frozen=True)
class HalfWavePlate:
    """Fast axis at ``angle_deg`` from s; ``retardance_deg`` 180 for an ideal plate."""

    angle_deg: float
    retardance_deg: float = 180.0

    def mueller(self) -> np.ndarray:
        return retarder_mueller(math.radians(self.angle_deg), math.radians(self.retardance_deg))


@dataclass(frozen=True)
class PolarizingBeamSplitter:
    """The port that goes on to the sample: "transmitted" passes p, "reflected" passes s;
    ``extinction`` = t_pass / t_block (inf: ideal)."""

    port: str = "transmitted"
    t_pass: float = 1.0
    extinction: float = math.inf

    def __post_init__(self):
        if self.port not in PORTS:
            raise BeamOpticsError(f"PBS port must be one of {', '.join(PORTS)}, got {self.port!r}")
        if not (0.0 < self.t_pass <= 1.0):
            raise BeamOpticsError(f"PBS t_pass must be in (0, 1], got {self.t_pass!r}")
        if not self.extinction >= 1.0:
            raise BeamOpticsError(f"PBS extinction must be >= 1, got {self.extinction!r}")

    def mueller(self) -> np.ndarray:
        axis = math.pi / 2 if self.port == "transmitted" else 0.0
        return diattenuator_mueller(axis, self.t_pass, self.t_pass / self.extinction)


@dataclass(frozen=True)
class BeamOptics:
    """The laser's Stokes vector (lab frame above; default: 1 W linear s) and the elements it passes,
    in order."""

    elements: tuple = ()
    laser_stokes: tuple = (1.0, 1.0, 0.0, 0.0)

    def __post_init__(self):
        s = np.asarray(self.laser_stokes, float)
        if s.shape != (4,) or not np.all(np.isfinite(s)) or s[0] <= 0 or np.linalg.norm(s[1:]) > s[0] * (1 + 1e-12):
            raise BeamOpticsError(f"laser_stokes must be a physical Stokes vector (S0 > 0, |S1..S3| <= S0), "
                                  f"got {self.laser_stokes!r}")
        for k, e in enumerate(self.elements):
            if not hasattr(e, "mueller"):
                raise BeamOpticsError(f"elements[{k}]: {type(e).__name__} is not a Mueller element")

    def stokes(self) -> np.ndarray:
        S = np.asarray(self.laser_stokes, float)
        for e in self.elements:
            S = e.mueller() @ S
        return S


def beam_parts(S, tol: float = 1e-9):
    """Split a Stokes vector (lab frame) into what the engine's sources can carry:
    ``[(power, e_field or None), ...]``: the unpolarized part (S0 - P) and the linear part P with
    its field direction in the lab (x, y, z). Circular components are refused."""
    S = np.asarray(S, float)
    P = math.hypot(S[1], S[2])
    if abs(S[3]) > tol * max(S[0], 1e-300):
        raise BeamOpticsError(f"the beam after the optics is elliptical (S3 = {S[3]:.3g}); the engine's sources "
                              "are unpolarized or linear")
    parts: list[tuple[float, tuple[float, float, float] | None]] = []
    if S[0] - P > tol * S[0]:
        parts.append((S[0] - P, None))
    if P > tol * S[0]:
        a = 0.5 * math.atan2(S[2], S[1])  # from e1 = +y toward e2 = +x
        parts.append((P, (math.sin(a), math.cos(a), 0.0)))
    return parts
