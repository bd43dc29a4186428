"""Target sampling: at each BRDF scatter, with probability q = ``target_fraction`` the new
direction points at a uniform point of the (flat) target parts, else it is the material's own
draw; either way the weight is f cos / ((1 - q) pdf_brdf + q pdf_target) (one-sample MIS, balance
heuristic; Veach 1997, ch. 9), with pdf_target = d^2 / (A |cos_y|)."""
from __future__ import annotations

import numpy as np

from straylight.engine.capabilities import Capability
from straylight.engine.material_groups import brdf_and_pdf, by_material


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


def target_pdf(target, p, nf, dirs, eps):
    """Solid-angle density of area-sampling the flat target toward ``dirs`` from ``p``: d^2 / (A |cos_y|)
    (``target``: straylight.engine.compiled_scene.TargetSampler)."""
    tri_t = target.isect.first_triangle(p + eps * nf, dirs)
    hit = np.flatnonzero(tri_t >= 0)
    pdf_t = np.zeros(len(p))
    if len(hit):
        nt = target.geometry.normals[tri_t[hit]]
        cos_y = _dot(dirs[hit], nt)
        ok = np.abs(cos_y) > 1e-12
        dist = (target.plane_d[tri_t[hit]] - _dot(nt, p[hit])) / np.where(ok, cos_y, 1.0)
        pdf_t[hit] = np.where(ok, dist * dist / (target.geometry.area_mm2 * np.abs(np.where(ok, cos_y, 1.0))), 0.0)
    return pdf_t


def target_mixture(spec, target, ut, p, nf, frame, wo_world):
    """Directions, weights and densities of the mixture (``ut``: the 4 target uniforms per vertex;
    ``frame``: the vertices' LocalFrames; ``wo_world``: the material's draws)."""
    q = float(spec.options.estimator.target_fraction)
    use_t = ut[:, 0] < q
    wo_world = wo_world.copy()
    if use_t.any():
        y, _ = target.geometry.sample(ut[use_t, 1:4])
        v = y - p[use_t]
        wo_world[use_t] = v / np.linalg.norm(v, axis=1, keepdims=True)
    tb, bb, wi_loc = frame.tangent, frame.bitangent, frame.wi_local
    wo_loc = np.stack([_dot(wo_world, tb), _dot(wo_world, bb), _dot(wo_world, nf)], axis=-1)
    f = np.zeros(len(p))
    pdf_b = np.zeros(len(p))
    pol = spec.options.physics.polarization
    for rows, (fv, pv) in by_material(spec.materials, frame.material, lambda model, rows:
            brdf_and_pdf(model, wi_loc[rows], wo_loc[rows], pol)):
        f[rows] = fv
        pdf_b[rows] = pv
    mix = (1.0 - q) * pdf_b + q * target_pdf(target, p, nf, wo_world, spec.eps)
    cos_o = wo_loc[:, 2]
    good = (cos_o > 0) & (mix > 0)
    weight = np.where(good, f * cos_o / np.where(good, mix, 1.0), 0.0)
    return wo_world, weight, np.where(good, mix, 0.0)


class TargetMixture:
    """Per batch (the target strategy's state, straylight.engine.strategies.target_mis): the walk's
    direction density at the scatter vertices of kinds that mix in target sampling
    (Capability.TARGET_MIS), (1 - q) pdf_brdf + q pdf_target, which next-event estimation weighs its
    samples against (straylight.engine.nee)."""

    def __init__(self, target, fraction: float, eps: float):
        self.target, self.q, self.eps = target, float(fraction), eps

    def density(self, event, verts):
        """For the scatter vertices ``verts`` (rows of the event): ``mix(pdf, vertex, dirs)``, which
        turns the BRDF densities ``pdf`` of directions ``dirs`` at the vertices ``verts[vertex]`` into
        the walk's (in place where only some vertices mix; returned); None when none of them mixes."""
        hit = event.hits
        mixed = event.capabilities.at(Capability.TARGET_MIS, hit.part[verts])
        if not mixed.any():
            return None
        every = bool(mixed.all())
        target, q, eps, p, nf = self.target, self.q, self.eps, hit.point_mm, hit.facing_normal

        def mix(pdf, vertex, dirs):
            at = verts[vertex]
            if every:
                return (1 - q) * pdf + q * target_pdf(target, p[at], nf[at], dirs, eps)
            mx = np.flatnonzero(mixed[vertex])
            pdf[mx] = (1 - q) * pdf[mx] + q * target_pdf(target, p[at[mx]], nf[at[mx]], dirs[mx], eps)
            return pdf

        return mix
