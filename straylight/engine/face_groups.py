"""Face groups of the vertex tables (first_vertex, second_vertex): a group id per triangle from its part
and its normal quantised to 1/8 (one flat face of a part, or a band of a curved one)."""
from __future__ import annotations

import numpy as np


def dense_row_ids(key: np.ndarray) -> np.ndarray:
    """``np.unique(key, axis=0, return_inverse=True)[1]`` for an (n, k) int64 array, the same ids: each row
    packed into one int64 in mixed radix (per column, value minus the column's minimum), which keeps the
    rows' lexicographic order, then a 1-D unique (a sort of n integers instead of n structured rows)."""
    if len(key) == 0:
        return np.zeros(0, np.int64)
    low = key.min(axis=0)
    span = key.max(axis=0) - low + 1
    if float(np.prod(span.astype(np.float64))) >= 2.0**62:  # does not fit one int64: the row sort
        return np.unique(key, axis=0, return_inverse=True)[1].ravel()
    packed = np.zeros(len(key), np.int64)
    for c in range(key.shape[1]):
        packed = packed * span[c] + (key[:, c] - low[c])
    return np.unique(packed, return_inverse=True)[1].ravel()


def face_groups(spec, comp, tris) -> np.ndarray:
    """A group id per triangle of ``tris`` (dense, in the lexicographic order of (part, round(8 n)))."""
    key = np.concatenate([spec.triangle_part[tris][:, None].astype(np.int64),
                          np.round(comp.normals[tris] * 8).astype(np.int64)], axis=1)
    return dense_row_ids(key)
