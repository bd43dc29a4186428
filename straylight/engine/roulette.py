"""Russian roulette, the one rule of every walk: the engine's compiled advance
(:func:`straylight.engine.advance.advance`) and the thermal walk (straylight.thermal.walk) call it.

A weight ``w`` below the threshold ``thr`` (and above 0) survives with probability ``w / thr`` at
weight ``thr``, else ends (weight 0); a weight at or above ``thr`` goes on unchanged. Unbiased: the
expected weight after it is ``thr * (w / thr) = w`` (Kalos & Whitlock, *Monte Carlo Methods*, 2008,
sec. 6.5). ``u`` is the ray's uniform draw for it. The engine's numpy reference
(:func:`straylight.engine.advance.advance_numpy`) keeps an independent twin, so that the bit-identity
tests check the compiled rule against it."""
from __future__ import annotations

import numpy as np
from materials.jit_cache import njit


@njit(cache=True, nogil=True)
def survivor_weight(w, thr, u):
    """The weight after roulette of one ray of weight ``w`` (threshold ``thr``, uniform ``u``)."""
    if w < thr and w > 0:
        return thr if u * thr < w else 0.0
    return w


@njit(cache=True, nogil=True)
def survivor_weights(w, thr, u):
    """:func:`survivor_weight` of every ray: weights ``w`` (n,), one threshold ``thr``, uniforms ``u`` (n,)."""
    out = np.empty(len(w))
    for i in range(len(w)):
        out[i] = survivor_weight(w[i], thr, u[i])
    return out
