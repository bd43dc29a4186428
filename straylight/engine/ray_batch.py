"""The live rays of a batch as one structure of arrays (row i = one ray), passed whole to the
compiled kernels (numba takes a NamedTuple of arrays as one argument) and rebuilt, compacted, by
:func:`straylight.engine.advance.advance` after every event."""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from straylight.paths import KIND_DETECTOR, KIND_DIFFRACTION, KIND_SCATTER, KIND_SPECULAR

# event codes (also the path records' kinds; 0: the ray comes straight from its source)
EVENT_SOURCE, EVENT_SCATTER, EVENT_SPECULAR, EVENT_DETECTOR = 0, KIND_SCATTER, KIND_SPECULAR, KIND_DETECTOR
# a ray just bent at a diffracting edge (straylight.engine.diffraction); the detector code's value, which
# never appears as a live ray's last event
EVENT_DIFFRACTION = KIND_DIFFRACTION


class RayBatch(NamedTuple):
    """Live rays: ``ray`` is the ray's index in its batch (its id minus the batch's first id)."""

    ray: np.ndarray  # (n,) int64
    origin_mm: np.ndarray  # (n, 3)
    direction: np.ndarray  # (n, 3) unit
    weight_w: np.ndarray  # (n,) power carried, W
    last_event: np.ndarray  # (n,) int8: EVENT_SOURCE, EVENT_SCATTER or EVENT_SPECULAR
    last_pdf_per_sr: np.ndarray  # (n,) density of the last sampled direction (MIS with NEE; 0 if none)
    last_part: np.ndarray  # (n,) int64 part of the last event, -1 at the source
    path_key: np.ndarray  # (n,) uint64 hash of the events so far (path records only)
    depth: np.ndarray  # (n,) int64 events so far
    history: np.ndarray  # (n, path_depth) int16 event codes part * 4 + event, -1 padded; (0, K) unless recorded


def emitted_rays(origin_mm, direction, weight_w: float, path_depth: int, record_paths: bool) -> RayBatch:
    """The batch's rays as they leave their sources, all with the same weight."""
    n = len(origin_mm)
    return RayBatch(
        ray=np.arange(n, dtype=np.int64), origin_mm=origin_mm, direction=direction, weight_w=np.full(n, weight_w),
        last_event=np.zeros(n, dtype=np.int8), last_pdf_per_sr=np.zeros(n), last_part=np.full(n, -1, dtype=np.int64),
        path_key=np.zeros(n, dtype=np.uint64), depth=np.zeros(n, dtype=np.int64),
        history=np.full((n if record_paths else 0, int(path_depth)), -1, dtype=np.int16))
