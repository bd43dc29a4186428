"""Each ray's polarization during a batch (CONTRACTS §6.3): a Stokes vector in a
reference frame ``(e1, e2 = d x e1)`` carried with the ray (``materials.mueller`` conventions).

The state lives on the batch's ``DetectorRecords`` (as long as the batch) and is created lazily:
by the first Fresnel interface (``optical_surface``), or at once when a source is linearly
polarized. While no state exists every interaction treats light as unpolarized and pays nothing
for polarization (:func:`active_state` is one attribute look-up).

A state is valid only for the interaction right after the one that set it: ``depth`` stamps the
ray depth it is valid at; any interaction that does not set it (a depolarizing scatter) leaves it
stale, i.e. the light arrives unpolarized.
"""
from __future__ import annotations

import numpy as np

from materials.mueller import rotate_stokes
from materials.polarized_brdf import is_polarizing
from straylight.engine.options import TraceError
from straylight.polarization import UNPOLARIZED


class PolarizationState:
    """Per batch: each ray's Stokes vector (S0 = 1; the walk's weight carries the power), its frame
    vector e1, and the depth at which it is valid (stale when another interaction came between)."""

    def __init__(self, n_rays: int, source_polarization):
        self.stokes = np.zeros((n_rays, 4))
        self.stokes[:, 0] = 1.0
        self.e1 = np.zeros((n_rays, 3))
        self.depth = np.full(n_rays, -1, dtype=np.int64)
        self.source = source_polarization

    def store(self, ray, depth_in, stokes, e1):
        """Set the outgoing state of rays ``ray`` that arrived at depth ``depth_in`` (S0 normalised to 1)."""
        s0 = stokes[:, 0]
        self.stokes[ray] = stokes / np.where(s0 > 0, s0, 1.0)[:, None]
        self.e1[ray] = e1
        self.depth[ray] = depth_in + 1


def source_polarization(spec):
    pols = {getattr(s, "polarization", UNPOLARIZED) for s in spec.sources}
    if len(pols) > 1:
        raise TraceError("sources with different polarizations in one trace are not supported; trace them apart")
    return pols.pop()


def batch_state(event) -> PolarizationState:
    """The batch's polarization state, created on first use."""
    st = event.records.polarization
    if st is None:
        st = PolarizationState(event.tallies.n_rays, source_polarization(event.spec))
        event.records.polarization = st
    return st


def tracks_polarization(spec) -> bool:
    """Whether every batch carries a polarization state from its start: a linear source, or
    ``scatter_polarization = "on"`` and a material whose scatter depends on or changes the
    polarization (:func:`materials.polarized_brdf.is_polarizing`, cached per material).

    Under the default ``"auto"``, unpolarized light scattered by a polarizing material leaves it
    unpolarized (the partial polarization that scatter creates is dropped, as in the commercial
    codes with polarization off): a state starts only at a linear source or at the first Fresnel
    interface (``optical_surface``), and from there scatter follows it in full. ``"on"`` also
    follows what scatter creates from unpolarized light (x1.8 CPU on the 0.36M-triangle Z302
    assembly, whose second scatter then sees partially polarized light)."""
    if any(getattr(s, "polarization", UNPOLARIZED).is_linear for s in spec.sources):
        return True
    if spec.options.physics.scatter_polarization != "on":
        return False
    return any(is_polarizing(m) for m in spec.materials)


def active_state(event):
    """The batch's state if any ray can be polarized (:func:`tracks_polarization`, or a Fresnel
    interface met already), else None: a scene of unpolarized sources and non-polarizing materials
    pays a few attribute look-ups per interaction call."""
    st = event.records.polarization
    if st is not None:
        return st
    if tracks_polarization(event.spec):
        return batch_state(event)
    return None


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


def incoming_stokes(st: PolarizationState, ray, depth, d, s):
    """Stokes vectors (m, 4) of the arriving rays in the frame e1 = ``s`` (unpolarized where the
    state is stale; the source's linear state at depth 0)."""
    m = len(ray)
    S = np.zeros((m, 4))
    S[:, 0] = 1.0
    known = st.depth[ray] == depth
    if np.any(known):
        k = np.flatnonzero(known)
        S[k] = rotate_stokes(st.stokes[ray[k]], st.e1[ray[k]], s[k], d[k])
    if st.source.is_linear:
        fresh = np.flatnonzero(~known & (depth == 0))
        if len(fresh):
            e = np.tile(np.asarray(st.source.e_field, float), (len(fresh), 1))
            e -= _dot(e, d[fresh])[:, None] * d[fresh]
            e /= np.linalg.norm(e, axis=1)[:, None]
            S[fresh] = rotate_stokes(np.tile([1.0, 1.0, 0.0, 0.0], (len(fresh), 1)), e, s[fresh], d[fresh])
    return S
