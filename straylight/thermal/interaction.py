"""The surface interaction of a thermal walk's hit: the engine's surface response, unpolarized.

No physics of its own: per material (and side) it calls what the engine's ``surface_response``
calls (straylight.engine.interactions.surface_response), chosen by the same rule on the material's
declared flags (``surface_response.material_class``):

- a pure scatterer: the engine's local frame (``brdf_scatter.local_frame``), the material's own
  draw ``Material.sample`` and the engine's return to world (``brdf_scatter.to_world_numpy``: weight
  zero below the horizon);
- a Fresnel surface (a ``specular`` or ``dielectric`` component, with or without lobes): the branch
  by expected power (``surface_geometry.fresnel_branches``, from ``Material.smooth_coefficients``
  and the lobes' reflectance), the lobe's draw with the branch uniform re-used
  (``surface_geometry.lobe_uniforms``), and the reflected / refracted rays with their weights
  (``surface_geometry.delta_branches``), for unpolarized light (Stokes (1, 0, 0, 0): the mean of s
  and p).

What thermal leaves out (docs/thermal.md, "Limits"): facet normals (no refinement onto analytic
surfaces), unpolarized light, no bulk absorption in dielectrics (the path length passed is zero:
thermal has no bulk emission either, so the medium neither absorbs nor emits). ``mirror`` parts
reflect with the trace's mirror reflectance, as the engine's ``delta_reflection``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from materials.smooth import reflect
from straylight.engine.interactions.brdf_scatter import LocalFrames, local_frame, to_world_numpy
from straylight.engine.interactions.surface_response import FRESNEL, material_class
from straylight.engine.surface_geometry import delta_branches, fresnel_branches, lobe_uniforms

UNPOLARIZED_STOKES = np.array([1.0, 0.0, 0.0, 0.0])


@dataclass
class Outgoing:
    direction: np.ndarray
    throughput: np.ndarray
    side: np.ndarray  # +1 leaves on the incident side, -1 crosses the surface
    delta: np.ndarray  # bool: a specular or refracted direction (NEE cannot reach it)


def interact(ts, sides, hit, rows, d, u) -> Outgoing:
    """Continuing hits ``rows`` (of ``hit``, a straylight.thermal.walk.Hit; surface or mirror parts)
    with incoming directions ``d`` (n, 3) and uniforms ``u`` (n, EVENT_COLUMNS: 0 the branch, 1..3
    the material's draw)."""
    n = len(rows)
    out = Outgoing(np.zeros((n, 3)), np.zeros(n), np.ones(n), np.zeros(n, bool))
    part = hit.part[rows]
    nf = hit.facing[rows]
    side = np.where(hit.front[rows], 0, 1)
    mirror = ts.is_role("mirror")[part]
    if mirror.any():
        out.direction[mirror] = reflect(d[mirror], nf[mirror])
        out.throughput[mirror] = ts.mirror_reflectance
        out.delta[mirror] = True
    surf = np.flatnonzero(~mirror)
    if len(surf) == 0:
        return out
    idx = sides.material_index[part[surf], side[surf]]
    for key in np.unique(idx):  # one call per material and side (a dielectric's back differs)
        for back in (0, 1):
            sel = surf[(idx == key) & (side[surf] == back)]
            if len(sel):
                _interact_material(sides.models[key], back == 1, d[sel], nf[sel], u[sel], out, sel)
    return out


def _sample_lobes(m, d, nf, wi, tb, bb, u3):
    """The material's own draw at the hits (local frame ``tb, bb, nf``): world directions and
    weights f cos / pdf (zero below the horizon)."""
    smp = m.sample(wi, u3, "u")
    frame = LocalFrames(tb, bb, wi, np.zeros(len(d), np.int64), u3)
    direction, weight, _pdf = to_world_numpy(smp.wo, smp.weight, smp.pdf_per_sr, frame, np.arange(len(d)), nf)
    return direction, weight


def _interact_material(m, back, d, nf, u, out, sel):
    """One material and side: the engine's pure-scatter or Fresnel response (module docstring)."""
    tb, bb, wi = local_frame(d, nf)
    k = len(d)
    if material_class(m) != FRESNEL:  # scatter lobes only
        out.direction[sel], out.throughput[sel] = _sample_lobes(m, d, nf, wi, tb, bb, u[:, 1:4])
        return
    cos_i = np.clip(-np.einsum("ij,ij->i", d, nf), 0.0, 1.0)
    S = np.tile(UNPOLARIZED_STOKES, (k, 1))
    br = fresnel_branches((m,), np.zeros(k, np.int64), np.ones(k, bool), np.full(k, bool(back)), cos_i,
                          np.zeros(k), S, u[:, 0])
    direction = d.copy()
    throughput = np.zeros(k)
    side = np.ones(k, dtype=np.int8)
    lb = np.flatnonzero(br.lobe)
    if len(lb):
        dirs, weight = _sample_lobes(m, d[lb], nf[lb], wi[lb], tb[lb], bb[lb],
                                     lobe_uniforms(u[lb, 1:4], u[lb, 0], br.P_l[lb]))
        direction[lb] = dirs
        throughput[lb] = weight / br.P_l[lb]
    delta_branches(br, d, nf, S, direction, throughput, np.zeros((k, 4)), side)
    out.direction[sel] = direction
    out.throughput[sel] = throughput
    out.side[sel] = side
    out.delta[sel] = br.refl | br.trans
