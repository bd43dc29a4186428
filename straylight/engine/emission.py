"""Emission: each ray picks a source with probability proportional to its power and is emitted by
the source's ``emit(u (n, 4)) -> (origins, directions)``; origins are lifted ``eps`` off the
source's plane toward where each ray goes, so a source laid on a surface (a Lambertian disk on a
detector, for a backward trace) does not hit it."""
from __future__ import annotations

import numpy as np
from materials.jit_cache import njit

from straylight.engine.draws import EMISSION_COLUMNS
from straylight.engine.vec3 import dot3
from straylight.rng import CHUNK_RAYS


@njit(cache=True, nogil=True)
def lift_origins(o, d, normal, eps):
    """Emitted origins moved eps along the source plane's normal toward each ray's side (in place):
    o + eps sign(d . n) n, with sign(0) = +1."""
    n0, n1, n2 = normal[0], normal[1], normal[2]
    for i in range(o.shape[0]):
        s = eps if dot3(d[i, 0], d[i, 1], d[i, 2], n0, n1, n2) >= 0 else -eps
        o[i, 0] = o[i, 0] + s * n0
        o[i, 1] = o[i, 1] + s * n1
        o[i, 2] = o[i, 2] + s * n2
    return o


def emit(source, u, eps):
    """Origins (lifted off the source's plane) and directions of ``source.emit(u)``."""
    o, d = source.emit(u)
    normal = getattr(source, "normal", None)
    if normal is None:
        return o + eps * d, d
    o = np.array(o, dtype=np.float64, order="C")  # a copy: the source's array is left alone
    d = np.ascontiguousarray(d, dtype=np.float64)
    return lift_origins(o, d, np.ascontiguousarray(normal, dtype=np.float64), float(eps)), d


def emit_batch(spec, draws, n, buf=None, on_uniforms=None):
    """Emission of a batch of ``n`` rays: chunk k draws (rays in chunk, 5) uniforms first; returns
    origins, directions (n, 3), contiguous and not sharing memory with ``buf``. ``on_uniforms(u)``,
    if given, sees (and may move, straylight.engine.entrance_sampling) the uniforms before the sources do."""
    u = np.empty((n, EMISSION_COLUMNS)) if buf is None else buf[:n * EMISSION_COLUMNS].reshape(n, EMISSION_COLUMNS)
    draws.fill(np.arange(n, dtype=np.int64), EMISSION_COLUMNS, u, CHUNK_RAYS)
    if on_uniforms is not None:
        on_uniforms(u)
    if len(spec.sources) == 1:
        o, d = emit(spec.sources[0], u[:, 1:5], spec.eps)
    else:
        powers = np.array([s.power_w for s in spec.sources], dtype=np.float64)
        o = np.empty((n, 3))
        d = np.empty((n, 3))
        cum = np.cumsum(powers) / float(powers.sum())
        which = np.minimum(np.searchsorted(cum, u[:, 0], side="right"), len(powers) - 1)
        for s, src in enumerate(spec.sources):
            sel = which == s
            if sel.any():
                o[sel], d[sel] = emit(src, u[sel, 1:5], spec.eps)
    o = np.ascontiguousarray(o, dtype=np.float64)
    d = np.ascontiguousarray(d, dtype=np.float64)
    if buf is not None and np.may_share_memory(d, buf):  # a source that returns views of its uniforms:
        d = d.copy()  # the scratch is refilled every event
    if buf is not None and np.may_share_memory(o, buf):
        o = o.copy()
    return o, d
