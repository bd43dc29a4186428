"""``delta_reflection``: mirror parts reflect specularly about the (incident-side) normal,
d' = d - 2 (d . n) n, with weight x ``TraceOptions.mirror_reflectance``; a delta event (no NEE,
pdf 0: a later walk hit on a detector counts fully)."""
from __future__ import annotations

import numpy as np
from numba import njit

from straylight.engine.event import outgoing
from straylight.engine.interactions.registry import Interaction, register_interaction
from straylight.engine.ray_batch import EVENT_SPECULAR
from straylight.engine.vec3 import dot3, dot_rows


@njit(cache=True, nogil=True)
def reflect(rows, d, nf, out):
    """out[k] = d - 2 (d . n) n for the rays ``rows``."""
    for k in range(len(rows)):
        i = rows[k]
        dn = dot3(d[i, 0], d[i, 1], d[i, 2], nf[i, 0], nf[i, 1], nf[i, 2])
        out[k, 0] = d[i, 0] - 2.0 * dn * nf[i, 0]
        out[k, 1] = d[i, 1] - 2.0 * dn * nf[i, 1]
        out[k, 2] = d[i, 2] - 2.0 * dn * nf[i, 2]
    return out


def reflect_numpy(rows, d, nf, out):
    dn = dot_rows(d[rows], nf[rows])
    out[:] = d[rows] - 2.0 * dn[:, None] * nf[rows]
    return out


@register_interaction
class DeltaReflection(Interaction):
    name = "delta_reflection"

    def interact(self, event, selection):
        rows = np.ascontiguousarray(event.vertex_rows(selection))
        direction = event.kernels.reflect(rows, event.rays.direction, event.hits.facing_normal, np.empty((len(rows), 3)))
        reflectance = np.full(len(rows), float(event.spec.options.mirror_reflectance))
        return outgoing(direction, reflectance, np.zeros(len(rows)), EVENT_SPECULAR)
