"""Path keys in compiled code: the splitmix64 fold of :func:`straylight.paths.mix_key`."""
from __future__ import annotations

import numpy as np
from materials.jit_cache import njit

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)


@njit(cache=True, nogil=True, inline="always")
def mix_key1(h, code):
    """splitmix64 fold of one event code (same as straylight.paths.mix_key)."""
    x = (h ^ (np.uint64(code) + np.uint64(1))) * _GOLDEN
    x = (x ^ (x >> np.uint64(30))) * _M1
    x = (x ^ (x >> np.uint64(27))) * _M2
    return x ^ (x >> np.uint64(31))
