"""``delta_reflection``: mirror parts reflect specularly about the (incident-side) normal,
d' = d - 2 (d . n) n, with weight x ``PhysicsOptions.mirror_reflectance``; a delta event (no NEE,
pdf 0: a later walk hit on a detector counts fully).

Polarization (CONTRACTS §6.3: role ``mirror`` is a ``specular`` surface with the trace's mirror
reflectance R): the Jones matrix is ``diag(r_s, r_p) = sqrt(R) diag(-1, +1)`` in the s/p basis of
:func:`materials.fresnel.fresnel_amplitudes` (an ideal mirror: no diattenuation, no retardance),
so the Mueller matrix is ``R diag(1, 1, -1, -1)`` (:func:`materials.mueller.interface_mueller`):
the power is R whatever the polarization, and a polarized ray leaves with its Stokes vector
re-expressed in the reflected frame (e1 = s; S2, S3 change sign). Only rays of a batch whose
polarization is tracked (straylight.engine.interactions.stokes) pay for it.
"""
from __future__ import annotations

import numpy as np
from materials.jit_cache import njit

from materials.mueller import s_vector
from straylight.engine.event import outgoing
from straylight.engine.interactions.registry import Capability, Interaction, register_interaction
from straylight.engine.interactions.stokes import active_state, incoming_stokes
from straylight.engine.ray_batch import EVENT_SPECULAR
from straylight.engine.vec3 import dot3, dot_rows, take_rows


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
    roles = ("mirror",)
    capabilities = Capability.NONE  # a delta event: no NEE, no area sampling; carries polarization, creates none

    def interact(self, event, selection):
        rows = np.ascontiguousarray(event.vertex_rows(selection))
        direction = event.kernels.reflect(rows, event.rays.direction, event.hits.facing_normal, np.empty((len(rows), 3)))
        reflectance = np.full(len(rows), float(event.spec.options.physics.mirror_reflectance))
        st = active_state(event)
        if st is not None and len(rows):
            carry_polarization(st, event, rows)
        return outgoing(direction, reflectance, np.zeros(len(rows)), EVENT_SPECULAR)


#: Mueller matrix of an ideal mirror per unit reflectance (Jones diag(-1, +1) in the s/p basis).
IDEAL_MIRROR_MUELLER = np.diag([1.0, 1.0, -1.0, -1.0])


def carry_polarization(st, event, rows):
    """Apply :data:`IDEAL_MIRROR_MUELLER` to the arriving Stokes vectors (frame e1 = s = d x n)
    and store them for the reflected rays (same e1: s is normal to the plane of incidence)."""
    rays = event.rays
    d = take_rows(rays.direction, rows)
    s = s_vector(d, take_rows(event.hits.facing_normal, rows))
    S = incoming_stokes(st, rays.ray[rows], rays.depth[rows], d, s)
    st.store(rays.ray[rows], rays.depth[rows], S @ IDEAL_MIRROR_MUELLER.T, s)
