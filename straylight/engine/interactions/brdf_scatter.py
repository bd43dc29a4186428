"""The scatter response (``surface_response`` parts whose material has no delta component,
straylight.engine.interactions.surface_response): the material samples the new direction itself
(``material.sample(wi, u) -> wo, weight = f cos / pdf, pdf``; materials/base.py), next-event
estimation toward the detectors from the vertex (straylight.engine.nee), and, with target parts,
the one-sample MIS mixture with area sampling of the target (straylight.engine.targets).

Materials are two-sided: the local frame's z is the geometric normal turned toward the incoming
ray (Duff et al. 2017 basis, as straylight.sources.orthonormal_basis); light leaves on the
incident side only. Kernels :func:`frames` and :func:`to_world` with their numpy twins (same bits).

Polarization (CONTRACTS §6.3): the material's Mueller BRDF (materials.polarized_brdf) scatters
each ray's Stokes vector; straylight.engine.interactions.scatter_polarization. A scene of
unpolarized sources and non-polarizing materials takes the unpolarized path and pays nothing.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from materials.jit_cache import njit

from straylight.engine import nee
from straylight.engine.event import outgoing
from straylight.engine.interactions.registry import Capability, Handler
from straylight.engine.interactions.scatter_polarization import arriving
from straylight.engine.material_groups import by_material
from straylight.engine.ray_batch import EVENT_SCATTER
from straylight.engine.targets import target_mixture
from straylight.engine.vec3 import dot3, dot_rows, take_rows, tangent_frame


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
        t0, t1, t2, b0, b1, b2 = tangent_frame(x, y, z)
        tb[s, 0], tb[s, 1], tb[s, 2] = t0, t1, t2
        bb[s, 0], bb[s, 1], bb[s, 2] = b0, b1, b2
        w0, w1, w2 = -d[i, 0], -d[i, 1], -d[i, 2]
        wi_loc[s, 0] = dot3(w0, w1, w2, t0, t1, t2)
        wi_loc[s, 1] = dot3(w0, w1, w2, b0, b1, b2)
        wi_loc[s, 2] = dot3(w0, w1, w2, x, y, z)
    return tb, bb, wi_loc, mat, u_s


def local_frame(d, n):
    """(tangent, bitangent, incoming direction in the frame) for rays of directions ``d`` (m, 3) at
    facing normals ``n`` (m, 3): the numpy form of :func:`frames` (also thermal's reverse walk)."""
    x, y, z = n[:, 0], n[:, 1], n[:, 2]
    sign = np.where(z >= 0, 1.0, -1.0)
    a = -1.0 / (sign + z)
    b = x * y * a
    tb = np.stack([1.0 + sign * x * x * a, sign * b, -sign * x], axis=-1)
    bb = np.stack([b, sign + y * y * a, -y], axis=-1)
    wi = -d
    wi_loc = np.stack([dot_rows(wi, tb), dot_rows(wi, bb), dot_rows(wi, n)], axis=-1)
    return tb, bb, wi_loc


def frames_numpy(verts, d, nf, part, part_material, U):
    """:func:`frames` in vectorised numpy (the reference)."""
    tb, bb, wi_loc = local_frame(d[verts], nf[verts])
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


class BrdfScatter(Handler):
    """The pure-scatter fast path of ``surface_response`` (no Fresnel branch); its capabilities are
    the materials' (``SurfaceResponse.capabilities_for``)."""

    def interact(self, event, selection):
        spec, kern, hit = event.spec, event.kernels, event.hits
        verts = np.ascontiguousarray(event.vertex_rows(selection))
        frame = LocalFrames(*kern.frames(verts, event.rays.direction, hit.facing_normal, hit.part,
                                         spec.part_material, event.uniforms))
        w_vertex = event.vertex_weights(verts)
        arr = arriving(event, verts, frame)
        if event.settings.nee and self.allows(Capability.NEE) and len(event.scene.det_parts):
            nee.estimate(event, verts, frame, w_vertex, evaluate=None if arr is None else arr.nee_evaluate(spec.materials))
        n = len(verts)
        wo = np.empty((n, 3))
        weight = np.empty(n)
        pdf = np.empty(n)
        pol = spec.options.physics.polarization
        for rows, smp in by_material(spec.materials, frame.material,
                                     lambda model, rows: model.sample(take_rows(frame.wi_local, rows),
                                                                      take_rows(frame.u_sample, rows), pol)):
            wo[rows] = smp.wo
            weight[rows] = smp.weight
            pdf[rows] = smp.pdf_per_sr
        wo_world, weight, pdf = kern.to_world(wo, weight, pdf, frame, verts, hit.facing_normal)
        target = event.scene.target if self.allows(Capability.TARGET_MIS) else None
        if target is not None:
            col = event.columns.target
            wo_world, weight, pdf = target_mixture(spec, target, event.uniforms[verts, col:col + 4],
                                                   take_rows(hit.point_mm, verts), take_rows(hit.facing_normal, verts),
                                                   frame, wo_world)
        if arr is not None:
            weight = weight * arr.scatter(event, verts, wo_world)
        return outgoing(wo_world, weight, pdf, EVENT_SCATTER)

