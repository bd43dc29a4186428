"""The Fresnel response: mirrors, windows and lenses that also scatter (CONTRACTS §5.1, §6.3).

The algorithm of ``surface_response`` (straylight.engine.interactions.surface_response) for
surface parts whose material has a ``specular`` or ``dielectric`` component (``ComponentFlags.DELTA``).
Per hit:

1. **Exact surface.** On a part with an analytic surface (geometry.analytic) the mesh hit is
   refined by Newton onto the surface and the exact normal replaces the facet's. A hit that
   refines back onto the ray's own origin (the ray met its surface's mesh a chord away) or
   outside the clear aperture passes through unchanged (a pass-through event).
2. **Polarization.** Each ray carries a Stokes vector in a reference frame (per batch, by ray
   id; ``materials.mueller`` conventions). Rays start unpolarized or linear (the sources'
   ``polarization``). At a Fresnel interface the frame is turned onto s and the Mueller matrix of
   the reflection or transmission is applied; the outgoing frame is s. A scatter lobe applies the
   material's Mueller BRDF, as on pure scatterers (``brdf_scatter``) (``scatter_polarization``).
3. **Branch by probability.** The expected powers of the three outcomes for this ray's
   polarization are E_l = rho_lobes (a rho_s + b rho_p), E_r = R, E_t = T, with
   ``a, b = (1 +- S1 / S0) / 2`` in the s/p basis and R, T after the lobes took their energy
   (``Material.smooth_coefficients``). One outcome is drawn with probability E_x / (E_l + E_r + E_t)
   and the weight is multiplied by E_x / P_x = E_l + E_r + E_t (the lobe branch by the lobe
   sample's own ``f cos / pdf`` over P_l, times f_pol / f_u): unbiased, and the weight of a ghost
   does not shrink with every reflection, so Russian roulette (which stays unbiased) never sees
   it as weak. Splitting would need several outgoing rays per hit, which the walk does not carry;
   ``delta_chain`` splits next to it (straylight.engine.delta_chain: runs of interfaces into a
   detector, the walk's own such hits dropped).
4. **Next-event estimation** from every hit toward the detectors for the lobes (with their s/p
   factors for this ray's polarization; MIS with the lobe branch uses the lobes' own pdf on both
   sides, so the weights sum to one).
5. **Bulk absorption.** A ray arriving on the back of a ``dielectric`` has crossed the medium: its
   weight is multiplied by ``exp(-alpha d)`` (``Dielectric.attenuation_per_mm``, d the segment).

Outgoing rays of the specular branches start on the exact line through the refined point, just
past the hit facet (the walk's eps offset is compensated), so a paraboloid images to < 1e-6 mm.
"""
from __future__ import annotations

import numpy as np

from materials.mueller import s_vector
from materials.polarized_brdf import is_polarizing
from straylight.engine import nee
from straylight.engine.material_groups import distinct
from straylight.engine.event import Interfaces, Outgoing
from straylight.engine.interactions.brdf_scatter import LocalFrames
from straylight.engine.interactions.registry import Capability, Handler
from straylight.engine.interactions.scatter_polarization import Arriving
from straylight.engine.interactions.stokes import batch_state, incoming_stokes
from straylight.engine.ray_batch import EVENT_SCATTER, EVENT_SPECULAR
from straylight.engine.surface_geometry import (delta_branches, fresnel_branches, lobe_uniforms, refine_on_surfaces,
                                                side_material)
from straylight.engine.vec3 import take_rows


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


class OpticalSurface(Handler):
    """The Fresnel + lobes path of ``surface_response``; its capabilities are the materials'
    (``SurfaceResponse.capabilities_for``: NEE from the lobes, no area sampling, the interface
    strategies, POLARIZES where a component polarizes)."""

    def interact(self, event, selection):
        spec, hit, rays = event.spec, event.hits, event.rays
        rows = np.ascontiguousarray(event.vertex_rows(selection))
        m = len(rows)
        if m == 0:
            return Outgoing(np.empty((0, 3)), np.empty(0), np.empty(0), np.empty(0, np.int8), np.empty(0, np.int8))
        st = batch_state(event)
        d = take_rows(rays.direction, rows)
        part = hit.part[rows]
        front, facing, exact, refined, passing = refine_on_surfaces(
            spec, part, take_rows(rays.origin_mm, rows), d, hit.distance_mm[rows], rays.last_part[rows],
            hit.cos_in[rows] < 0, take_rows(hit.facing_normal, rows).copy())
        live = ~passing
        hit.facing_normal[rows[live]] = facing[live]
        mat = side_material(spec, part, front)
        back = ~front
        cos_i = np.clip(-_dot(d, facing), 0.0, 1.0)
        s = s_vector(d, facing)
        S = incoming_stokes(st, rays.ray[rows], rays.depth[rows], d, s)
        U = event.uniforms
        u = U[rows, event.columns.sample].copy()
        br = fresnel_branches(spec.materials, mat, live, back, cos_i, hit.distance_mm[rows], S, u)
        rs, rp, ts, tp, cos_t, eta, bulk = br.fresnel
        rho_s, rho_p, E_r, E_t, P_l = br.rho_s, br.rho_p, br.E_r, br.E_t, br.P_l
        lobe, refl, trans, dead = br.lobe, br.refl, br.trans, br.dead

        direction = d.copy()
        throughput = np.ones(m)
        pdf = np.zeros(m)
        code = np.full(m, EVENT_SPECULAR, dtype=np.int8)
        side_out = np.ones(m, dtype=np.int8)
        S_new = np.zeros((m, 4))
        S_new[:, 0] = 1.0
        e1_new = s.copy()

        # --- the strategies that act at interfaces (reflection_split, delta_chain), where the kind allows them
        if event.interface_hooks:
            at_interfaces = Interfaces(rows=rows, live=live, refined=refined, exact=exact, facing=facing, d=d, s=s,
                                       S=S, fresnel=(rs, rp, ts, tp, cos_t, eta, bulk), E_r=E_r, E_t=E_t,
                                       reflected=refl, transmitted=trans, passing=passing)
            for strategy, state in event.interface_hooks:
                if self.allows(strategy.estimator.capability):
                    strategy.at_interfaces(state, event, at_interfaces)
        # --- lobes: NEE from every vertex whose material scatters, and the lobe branch
        has_lobes = live & ((rho_s > 0) | (rho_p > 0))
        if np.any(has_lobes):
            self._lobes(event, rows, has_lobes, lobe, mat, S, P_l, u, direction, throughput, pdf, code,
                        (st, s, S_new, e1_new))
        # --- specular reflection and refraction (Mueller matrices in the s/p basis)
        delta_branches(br, d, facing, S, direction, throughput, S_new, side_out)
        throughput[dead] = 0.0
        throughput *= bulk
        # pass-through: the ray goes on unchanged (same event kind and pdf for the MIS at a detector)
        pt = np.flatnonzero(passing)
        if len(pt):
            direction[pt] = d[pt]
            throughput[pt] = 1.0
            code[pt] = rays.last_event[rows[pt]]
            pdf[pt] = rays.last_pdf_per_sr[rows[pt]]
            side_out[pt] = -1
        # specular rays leave on the exact line through the refined point, past the hit facet
        spec_rows = np.flatnonzero((refl | trans) & refined)
        if len(spec_rows):
            self._place_on_exact_line(event, rows[spec_rows], exact[spec_rows], direction[spec_rows],
                                      facing[spec_rows], side_out[spec_rows])
        # polarization bookkeeping (lobe rows were set by _lobes); a pass-through keeps its arriving
        # state, here in the frame s
        S_new[passing] = S[passing]
        st.store(rays.ray[rows], rays.depth[rows], S_new, e1_new)
        return Outgoing(direction=np.ascontiguousarray(direction), throughput=throughput, pdf_per_sr=pdf,
                        event=code, side=side_out)

    # ------------------------------------------------------------------ lobes

    def _lobes(self, event, rows, has_lobes, lobe, mat, S, P_l, u, direction, throughput, pdf, code, pol_out):
        """NEE and the lobe branch; the polarized scatter (Mueller BRDF on the arriving S, the
        scattered state into ``pol_out = (state, s, S_new, e1_new)``) as on pure scatterers
        (straylight.engine.interactions.scatter_polarization)."""
        spec, kern, hit = event.spec, event.kernels, event.hits
        st, s, S_new, e1_new = pol_out
        sel = np.flatnonzero(has_lobes)
        verts = np.ascontiguousarray(rows[sel])
        frame = LocalFrames(*kern.frames(verts, event.rays.direction, hit.facing_normal, hit.part,
                                         spec.part_material, event.uniforms))
        frame = frame._replace(material=mat[sel])
        nf = take_rows(hit.facing_normal, verts)
        s_local = np.stack([_dot(s[sel], frame.tangent), _dot(s[sel], frame.bitangent), _dot(s[sel], nf)], axis=-1)
        polar_mat = np.array([is_polarizing(m) for m in spec.materials], bool)[mat[sel]]
        arr = Arriving(st, S[sel], s_local, polar_mat, frame, event.rays.ray[verts], event.rays.depth[verts])
        if event.settings.nee and self.allows(Capability.NEE) and len(event.scene.det_parts):
            w_vertex = event.vertex_weights(verts)
            nee.estimate(event, verts, frame, w_vertex, evaluate=arr.nee_evaluate(spec.materials))
        # the lobe branch: the material's own draw, u[:, 0] re-used within the branch's interval
        lb = np.flatnonzero(lobe[sel])
        if len(lb) == 0:
            return
        at = sel[lb]
        wi = take_rows(frame.wi_local, lb)
        u3 = lobe_uniforms(take_rows(frame.u_sample, lb), u[at], P_l[at])
        wo = np.empty((len(lb), 3))
        weight = np.empty(len(lb))
        pdf_l = np.empty(len(lb))
        mv = mat[at]
        for k in distinct(mv):
            g = np.flatnonzero(mv == k)
            smp = spec.materials[k].sample(wi[g], u3[g], "u")
            wo[g], weight[g], pdf_l[g] = smp.wo, smp.weight, smp.pdf_per_sr
        sub = LocalFrames(take_rows(frame.tangent, lb), take_rows(frame.bitangent, lb), wi, mv, u3)
        wo_world, weight, pdf_l = kern.to_world(wo, weight, pdf_l, sub, np.ascontiguousarray(rows[at]),
                                                hit.facing_normal)
        ratio, use, S_out, e1 = arr.scattered(event, verts, wo_world, subset=lb)
        weight = weight * ratio
        S_new[at[use]] = S_out
        e1_new[at[use]] = e1
        direction[at] = wo_world
        throughput[at] = weight / P_l[at]
        pdf[at] = pdf_l
        code[at] = EVENT_SCATTER

    # ------------------------------------------------------------------ origins

    @staticmethod
    def _place_on_exact_line(event, rows, p_exact, d_out, facing, side):
        """Set the hit point so that the walk's next origin (point + side eps facing) is
        ``p_exact + lam d_out``, with lam >= 0 the smallest that clears the hit facet's plane by
        2 eps on the outgoing side."""
        hit = event.hits
        eps = event.settings.eps_mm
        arrays = event.scene.arrays
        tri = event.tri[rows]
        ng = take_rows(arrays.normals, tri)
        cos_in = hit.cos_in[rows]
        nfg = np.where((cos_in < 0)[:, None], ng, -ng)  # facet normal toward the incoming ray
        h = (_dot(ng, p_exact) - arrays.plane_d[tri]) * np.where(cos_in < 0, 1.0, -1.0)
        sg = side.astype(float)
        g = _dot(d_out, nfg)
        need = sg * g > 0
        lam = np.where(need, np.maximum(0.0, (sg * 2.0 * eps - h) / np.where(need, g, 1.0)), 0.0)
        hit.point_mm[rows] = p_exact + lam[:, None] * d_out - (sg * eps)[:, None] * facing
