"""Small vector helpers shared by the compiled kernels and their numpy twins, written in the order
numpy evaluates them so both give the same bits: ``np.einsum("ij,ij->i", a, b)`` on (n, 3) rows
sums ``(a0 b0 + a2 b2) + a1 b1``; ``np.linalg.norm(v, axis=1)`` is ``sqrt((v0^2 + v1^2) + v2^2)``;
no fused multiply-add (numba does not contract without ``fastmath``)."""
from __future__ import annotations

import numpy as np
from materials.jit_cache import njit


@njit(cache=True, nogil=True, inline="always")
def dot3(a0, a1, a2, b0, b1, b2):
    """a . b in numpy's einsum order."""
    return (a0 * b0 + a2 * b2) + a1 * b1


@njit(cache=True, nogil=True, inline="always")
def tangent_frame(x, y, z):
    """(t0, t1, t2, b0, b1, b2): the tangent and bitangent of the unit normal (x, y, z), Duff et al. 2017's
    branchless basis, in the arithmetic order of straylight.sources.orthonormal_basis (the same bits)."""
    sign = 1.0 if z >= 0 else -1.0
    a = -1.0 / (sign + z)
    b = x * y * a
    return 1.0 + sign * x * x * a, sign * b, -sign * x, b, sign + y * y * a, -y


def take_rows(a, index):
    """``a[index]`` (a copy) for an integer index array, by ``np.take`` along the first axis: numpy's
    fancy indexing of the rows of a 2-D array is several times slower (the same elements, the same
    order). A boolean mask or a slice is indexed as it is."""
    if isinstance(index, slice):
        return a[index]
    index = np.asarray(index)
    if index.dtype == np.bool_:
        return a[index]
    return a.take(index, axis=0)


def dot_rows(a, b):
    """Row-wise a . b of (n, 3) arrays, in the order of :func:`dot3`."""
    return (a[:, 0] * b[:, 0] + a[:, 2] * b[:, 2]) + a[:, 1] * b[:, 1]


@njit(cache=True, nogil=True, inline="always")
def power_heuristic(p_this, p_other):
    """MIS weight p^2 / (p^2 + q^2) of the strategy with density p_this (Veach 1997, eq. 9.13)."""
    a = p_this * p_this
    b = p_other * p_other
    total = a + b
    return a / total if total > 0 else 0.0


def power_heuristic_rows(p_this, p_other):
    """:func:`power_heuristic` on arrays."""
    a = np.asarray(p_this, dtype=np.float64) ** 2
    b = np.asarray(p_other, dtype=np.float64) ** 2
    total = a + b
    return np.where(total > 0, a / np.where(total > 0, total, 1.0), 0.0)
