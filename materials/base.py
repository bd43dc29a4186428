"""Frames, conventions and the BRDF protocol shared by every model.

Sample frame (CONTRACTS §1): z is the surface normal. ``wi`` points toward the
source and ``wo`` toward the detector; both are unit vectors pointing away from
the surface. Incidence comes from ``phi_i = pi``, so

    wi = (-sin theta_i, 0, cos theta_i),   specular wo = (sin theta_i, 0, cos theta_i)

and the specular direction has ``phi_r = 0``. Projected directions
(PHYSICS §1): ``beta = wo[:, :2]`` and ``beta0 = -wi[:, :2]``, so the Bragg
offset is ``beta - beta0 = wo[:, :2] + wi[:, :2]`` (symmetric in wi, wo).

Every model implements :class:`Brdf`. ``brdf`` never includes cos(theta_r);
``sample`` returns directions drawn from (approximately) f cos and the weight
``f cos(theta_r) / pdf`` so that the estimator is unbiased.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

POLARIZATIONS = ("s", "p", "u")


class MaterialError(ValueError):
    """Bad material parameters or file content; the message names what and where."""


def check_polarization(polarization: str) -> str:
    if polarization not in POLARIZATIONS:
        raise MaterialError(f"unknown polarization {polarization!r}: expected one of s, p, u")
    return polarization


def directions_from_angles(theta_i, theta_r, phi_r):
    """(theta_i, theta_r, phi_r) in radians -> (wi, wo), each (n, 3), sample frame."""
    theta_i, theta_r, phi_r = np.broadcast_arrays(
        np.atleast_1d(np.asarray(theta_i, float)),
        np.atleast_1d(np.asarray(theta_r, float)),
        np.atleast_1d(np.asarray(phi_r, float)),
    )
    wi = np.stack([-np.sin(theta_i), np.zeros_like(theta_i), np.cos(theta_i)], axis=-1)
    st = np.sin(theta_r)
    wo = np.stack([st * np.cos(phi_r), st * np.sin(phi_r), np.cos(theta_r)], axis=-1)
    return wi, wo


def angles_from_directions(wi, wo):
    """(wi, wo) -> (theta_i, theta_r, phi_r) radians, with phi_r measured from the
    specular half-plane (the plane of incidence is rotated so that phi_i = pi)."""
    wi = np.asarray(wi, float)
    wo = np.asarray(wo, float)
    theta_i = np.arccos(np.clip(wi[:, 2], -1.0, 1.0))
    theta_r = np.arccos(np.clip(wo[:, 2], -1.0, 1.0))
    phi_i = np.arctan2(wi[:, 1], wi[:, 0])
    phi_o = np.arctan2(wo[:, 1], wo[:, 0])
    phi_r = np.mod(phi_o - phi_i + np.pi, 2 * np.pi)  # phi_i -> pi
    return theta_i, theta_r, phi_r


def bragg_offset(wi, wo):
    """beta - beta0 = wo_xy + wi_xy, (n, 2)."""
    return np.asarray(wo)[:, :2] + np.asarray(wi)[:, :2]


def lobe_inputs(wi, wo, polarization: str):
    """The common start of every beta-centred lobe's ``brdf``: checks the polarization and returns
    ``(wi, wo, above, d)`` with float arrays, the both-above-the-horizon mask and ``beta - beta0``."""
    check_polarization(polarization)
    wi = np.asarray(wi, float)
    wo = np.asarray(wo, float)
    above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    return wi, wo, above, bragg_offset(wi, wo)


class PairGeometry:
    """Direction pairs (wi, wo) (n, 3) and what several lobes of a composite read of them (the
    both-above mask, the Bragg offset's r^2, the scatter azimuth, a lobe shape, a Rayleigh-Rice factor,
    ...), each made once by :meth:`get` under a key naming every input of its expression: a lobe that
    would form the same expression from the same inputs reads the same array (the same bits)."""

    __slots__ = ("wi", "wo", "_made")

    def __init__(self, wi, wo):
        self.wi = np.asarray(wi, float)
        self.wo = np.asarray(wo, float)
        self._made: dict = {}

    def get(self, key, make):
        """The value under ``key``, ``make()`` the first time (the arrays are shared: read them only)."""
        made = self._made
        if key not in made:
            made[key] = make()
        return made[key]

    def above(self) -> np.ndarray:
        """Both directions above the horizon."""
        return self.get("above", lambda: (self.wi[:, 2] > 0) & (self.wo[:, 2] > 0))

    def r2(self) -> np.ndarray:
        """|beta - beta0|^2 of the Bragg offset wo_xy + wi_xy (:func:`bragg_offset`; equal to the bit to
        wo_xy - beta0, beta0 = -wi_xy: x - (-y) is x + y in IEEE arithmetic)."""
        def make():
            d = bragg_offset(self.wi, self.wo)
            return d[:, 0] ** 2 + d[:, 1] ** 2
        return self.get("r2", make)


@dataclass(frozen=True)
class Sample:
    """Result of importance sampling.

    wo : (n, 3) sampled unit directions (sample frame; wo_z <= 0 means below the horizon)
    weight : (n,) f cos(theta_r) / pdf, zero for directions below the horizon
    pdf_per_sr : (n,) density of wo per steradian (0 where undefined)
    """

    wo: np.ndarray
    weight: np.ndarray
    pdf_per_sr: np.ndarray


@runtime_checkable
class Brdf(Protocol):
    """What every model (and every composite) provides. Arrays in, arrays out."""

    def brdf(self, wi: np.ndarray, wo: np.ndarray, polarization: str = "u") -> np.ndarray:
        """BRDF in 1/sr, without cos. wi, wo : (n, 3) unit vectors. Zero below the horizon."""

    def sample(self, wi: np.ndarray, u: np.ndarray, polarization: str = "u") -> Sample:
        """Draw wo for each wi from uniforms u : (n, 3) (u[:, 0] picks a component in
        composites, u[:, 1:] the direction). Deterministic in u."""

    def pdf(self, wi: np.ndarray, wo: np.ndarray, polarization: str = "u") -> np.ndarray:
        """Density per steradian of ``sample`` producing wo."""

    def to_dict(self) -> dict:
        """Component dict of CONTRACTS §5 (one entry of ``components``)."""


def brdf_angles(model: Brdf, theta_i, theta_r, phi_r=0.0, polarization: str = "u"):
    """Evaluate a model at angles in radians (broadcast); returns 1/sr."""
    wi, wo = directions_from_angles(theta_i, theta_r, phi_r)
    return model.brdf(wi, wo, check_polarization(polarization))
