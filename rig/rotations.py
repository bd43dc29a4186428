"""The one rotation helper of the rig: rotations about the lab's x and y axes (the goniometer's
axes: y is the stage axis in the plane of incidence x-z, x tilts the sample normal toward -y)."""
from __future__ import annotations

import numpy as np


def rotate_about_y(vec, angle_rad):
    """Rotate (..., 3) vectors about y so that (sin a, 0, cos a) -> (sin(a + angle), 0, cos(a + angle))."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    x, y, z = vec[..., 0], vec[..., 1], vec[..., 2]
    return np.stack([c * x + s * z, y, -s * x + c * z], axis=-1)


def rotate_about_x(vec, angle_rad):
    """Rotate (..., 3) vectors about x by ``angle_rad`` (right-handed: tilts +z toward -y)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    x, y, z = vec[..., 0], vec[..., 1], vec[..., 2]
    return np.stack([x, c * y - s * z, s * y + c * z], axis=-1)


def matrix_about_y(angle_rad: float) -> np.ndarray:
    """The 3x3 matrix of :func:`rotate_about_y` (``matrix @ v``)."""
    return rotate_about_y(np.eye(3), angle_rad).T


def matrix_about_x(angle_rad: float) -> np.ndarray:
    """The 3x3 matrix of :func:`rotate_about_x` (``matrix @ v``)."""
    return rotate_about_x(np.eye(3), angle_rad).T
