"""``brdf_scatter`` (surface parts): the material samples the new direction itself
(``material.sample(wi, u) -> wo, weight = f cos / pdf, pdf``; materials/base.py), next-event
estimation toward the detectors from the vertex (straylight.engine.nee), and, with target parts,
the one-sample MIS mixture with area sampling of the target (straylight.engine.targets).

Materials are two-sided: the local frame's z is the geometric normal turned toward the incoming
ray (Duff et al. 2017 basis, as straylight.sources.orthonormal_basis); light leaves on the
incident side only. Kernels :func:`frames` and :func:`to_world` with their numpy twins (same bits).

Polarization (CONTRACTS §6.3; straylight.engine.interactions.stokes): a ray that arrives
polarized (a linear source, or after a Fresnel interface or a mirror) is scattered with the first
row of the material's Mueller BRDF, ``f = M00 + M01 S1`` in the s/p basis of the vertex, i.e.
``f = (f_s + f_p)/2 + S1 (f_s - f_p)/2`` from the model's s and p BRDFs (:func:`polarized_f`), for
the walk's sampled direction (weight x f_pol / f_u) and for NEE. The scattered light leaves
unpolarized: M1j = M2j = M3j = 0 is assumed (exact for a Lambertian part; see docs/optics.md
for what the K-correlation/Rayleigh-Rice model defines). Unpolarized rays take exactly the old
path (``brdf(.., "u")``), and a batch without polarized light pays nothing.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from materials.mueller import s_vector
from straylight.engine import nee
from straylight.engine.event import outgoing
from straylight.engine.interactions.registry import Interaction, register_interaction
from straylight.engine.interactions.stokes import active_state, incoming_stokes, mix
from straylight.engine.material_groups import by_material
from straylight.engine.ray_batch import EVENT_SCATTER
from straylight.engine.targets import target_mixture
from straylight.engine.vec3 import dot3, dot_rows


class LocalFrames(NamedTuple):
    """Per scatter vertex: the local frame (tangent, bitangent, facing normal = z), the incoming
    direction in it, the material index and the 3 sampling uniforms."""

    tangent: np.ndarray  # (n, 3)
    bitangent: np.ndarray  # (n, 3)
    wi_local: np.ndarray  # (n, 3) toward where the ray came from, z > 0
    material: np.ndarray  # (n,) int64 index into spec.materials
    u_sample: np.ndarray  # (n, 3)


@njit(cache=True, nogil=True)
def frames(verts, d, nf, part, part_material, U):
    """The fields of :class:`LocalFrames` for the vertices ``verts`` (rows of the event)."""
    ns = len(verts)
    tb = np.empty((ns, 3))
    bb = np.empty((ns, 3))
    wi_loc = np.empty((ns, 3))
    mat = np.empty(ns, np.int64)
    u_s = np.empty((ns, 3))
    for s in range(ns):
        i = verts[s]
        mat[s] = part_material[part[i]]
        u_s[s, 0], u_s[s, 1], u_s[s, 2] = U[i, 0], U[i, 1], U[i, 2]
        x, y, z = nf[i, 0], nf[i, 1], nf[i, 2]
        sign = 1.0 if z >= 0 else -1.0
        a = -1.0 / (sign + z)
        b = x * y * a
        t0, t1, t2 = 1.0 + sign * x * x * a, sign * b, -sign * x
        b0, b1, b2 = b, sign + y * y * a, -y
        tb[s, 0], tb[s, 1], tb[s, 2] = t0, t1, t2
        bb[s, 0], bb[s, 1], bb[s, 2] = b0, b1, b2
        w0, w1, w2 = -d[i, 0], -d[i, 1], -d[i, 2]
        wi_loc[s, 0] = dot3(w0, w1, w2, t0, t1, t2)
        wi_loc[s, 1] = dot3(w0, w1, w2, b0, b1, b2)
        wi_loc[s, 2] = dot3(w0, w1, w2, x, y, z)
    return tb, bb, wi_loc, mat, u_s


def frames_numpy(verts, d, nf, part, part_material, U):
    """:func:`frames` in vectorised numpy (the reference)."""
    n = nf[verts]
    x, y, z = n[:, 0], n[:, 1], n[:, 2]
    sign = np.where(z >= 0, 1.0, -1.0)
    a = -1.0 / (sign + z)
    b = x * y * a
    tb = np.stack([1.0 + sign * x * x * a, sign * b, -sign * x], axis=-1)
    bb = np.stack([b, sign + y * y * a, -y], axis=-1)
    wi = -d[verts]
    wi_loc = np.stack([dot_rows(wi, tb), dot_rows(wi, bb), dot_rows(wi, n)], axis=-1)
    return tb, bb, wi_loc, part_material[part[verts]], U[verts, 0:3]


@njit(cache=True, nogil=True)
def to_world(wo, weight, pdf, frame, verts, nf):
    """Sampled local directions to world (renormalised); weight zero below the horizon."""
    ns = len(verts)
    out = np.empty((ns, 3))
    wt = np.empty(ns)
    tb, bb = frame.tangent, frame.bitangent
    for s in range(ns):
        i = verts[s]
        a, b, c = wo[s, 0], wo[s, 1], wo[s, 2]
        wt[s] = weight[s] if c > 0 else 0.0
        x0 = a * tb[s, 0] + b * bb[s, 0] + c * nf[i, 0]
        x1 = a * tb[s, 1] + b * bb[s, 1] + c * nf[i, 1]
        x2 = a * tb[s, 2] + b * bb[s, 2] + c * nf[i, 2]
        nrm = np.sqrt((x0 * x0 + x1 * x1) + x2 * x2)
        if not nrm > 0:
            nrm = 1.0
        out[s, 0], out[s, 1], out[s, 2] = x0 / nrm, x1 / nrm, x2 / nrm
    return out, wt, pdf


def to_world_numpy(wo, weight, pdf, frame, verts, nf):
    """:func:`to_world` in vectorised numpy (the reference)."""
    n = nf[verts]
    x = wo[:, :1] * frame.tangent + wo[:, 1:2] * frame.bitangent + wo[:, 2:3] * n
    nrm = np.sqrt((x[:, 0] * x[:, 0] + x[:, 1] * x[:, 1]) + x[:, 2] * x[:, 2])
    nrm = np.where(nrm > 0, nrm, 1.0)
    return x / nrm[:, None], np.where(wo[:, 2] > 0, weight, 0.0), pdf


@register_interaction
class BrdfScatter(Interaction):
    name = "brdf_scatter"

    def interact(self, event, selection):
        spec, kern, hit = event.spec, event.kernels, event.hits
        verts = np.ascontiguousarray(event.vertex_rows(selection))
        frame = LocalFrames(*kern.frames(verts, event.rays.direction, hit.facing_normal, hit.part,
                                         spec.part_material, event.uniforms))
        w_vertex = None if event.first_vertex is None else event.first_vertex.vertex_weights(event, verts)
        S = arriving_polarization(event, verts)
        if event.settings.nee and len(event.scene.det_parts):
            nee.estimate(event, verts, frame, w_vertex,
                         evaluate=None if S is None else polarized_evaluate(spec.materials, frame.material, S))
        n = len(verts)
        wo = np.empty((n, 3))
        weight = np.empty(n)
        pdf = np.empty(n)
        pol = spec.options.polarization
        for rows, smp in by_material(spec.materials, frame.material,
                                     lambda model, rows: model.sample(frame.wi_local[rows], frame.u_sample[rows], pol)):
            wo[rows] = smp.wo
            weight[rows] = smp.weight
            pdf[rows] = smp.pdf_per_sr
        wo_world, weight, pdf = kern.to_world(wo, weight, pdf, frame, verts, hit.facing_normal)
        target = event.scene.target
        if target is not None:
            col = event.columns.target
            wo_world, weight, pdf = target_mixture(spec, target, event.uniforms[verts, col:col + 4],
                                                   hit.point_mm[verts], hit.facing_normal[verts], frame, wo_world)
        if S is not None:
            weight = weight * polarized_ratio(spec.materials, frame, S, wo_world, hit.facing_normal[verts])
        return outgoing(wo_world, weight, pdf, EVENT_SCATTER)


def arriving_polarization(event, verts):
    """Stokes vectors (n, 4) of the rays arriving at ``verts`` in the s/p basis (e1 = s = d x n), or
    None when none of them is polarized (so unpolarized light costs one attribute look-up)."""
    if event.spec.options.polarization != "u":
        return None  # every vertex is evaluated for the trace's s or p (the twin's mode)
    st = active_state(event)
    if st is None:
        return None
    rays = event.rays
    d = rays.direction[verts]
    S = incoming_stokes(st, rays.ray[verts], rays.depth[verts], d, s_vector(d, event.hits.facing_normal[verts]))
    return S if np.any(S[:, 1] != 0.0) else None


def polarized_f(model, wi, wo, S):
    """The scattered BRDF for arriving Stokes ``S`` (S0 = 1): M00 + M01 S1 (:func:`stokes.mix`)."""
    return mix(model.brdf(wi, wo, "s"), model.brdf(wi, wo, "p"), S)


def polarized_evaluate(models, material, S):
    """NEE's ``evaluate(wi, wo, vertex)``: the unpolarized f and pdf as without polarization, and
    f for the arriving polarization where S1 != 0."""
    def evaluate(wi, wo, vertex):
        f = np.empty(len(wi))
        p = np.empty(len(wi))
        for rows, (fv, pv) in by_material(models, material[vertex], lambda model, rows: (
                model.brdf(wi[rows], wo[rows], "u"), model.pdf(wi[rows], wo[rows], "u"))):
            f[rows] = fv
            p[rows] = pv
        pol = np.flatnonzero(S[vertex, 1] != 0.0)
        if len(pol):
            mv = material[vertex[pol]]
            for k in np.unique(mv):
                g = pol[mv == k]
                f[g] = polarized_f(models[k], wi[g], wo[g], S[vertex[g]])
        return f, p
    return evaluate


def polarized_ratio(models, frame, S, wo_world, nf):
    """f_pol / f_u at the outgoing directions (1 for unpolarized rays): turns the walk's weight
    f_u cos / pdf into f_pol cos / pdf."""
    ratio = np.ones(len(S))
    pol = np.flatnonzero(S[:, 1] != 0.0)
    if len(pol) == 0:
        return ratio
    wo = wo_world[pol]
    wo_loc = np.stack([dot_rows(wo, frame.tangent[pol]), dot_rows(wo, frame.bitangent[pol]), dot_rows(wo, nf[pol])],
                      axis=-1)
    wi = frame.wi_local[pol]
    mv = frame.material[pol]
    for k in np.unique(mv):
        g = np.flatnonzero(mv == k)
        fu = models[k].brdf(wi[g], wo_loc[g], "u")
        fp = polarized_f(models[k], wi[g], wo_loc[g], S[pol[g]])
        ratio[pol[g]] = np.where(fu > 0, fp / np.where(fu > 0, fu, 1.0), 0.0)
    return ratio
