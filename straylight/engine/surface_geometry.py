"""The surface geometry and Fresnel coefficients of interface hits, shared by the interaction that branches
at them (straylight.engine.interactions.optical_surface) and the strategy that splits through runs of them
(straylight.engine.delta_chain): the mesh hit refined onto the part's analytic surface, the material of
the side that was hit, and the Fresnel amplitudes (``Material.smooth_coefficients``) with the bulk
attenuation of the medium crossed."""
from __future__ import annotations

import numpy as np

from materials.smooth import Dielectric

SELF_HIT_MM = 1e-6  # a refined hit this close to (or behind) the ray's origin on its own last part is spurious


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


def refine_on_surfaces(spec, part, origin, d, distance_mm, last_part, front, facing):
    """Mesh hits (``origin + distance_mm d`` on ``part``) refined onto the parts' analytic surfaces:
    (front, facing normal, exact point, refined, passing). ``front`` and ``facing`` (the facet's)
    are updated in place where refined; a hit that refines outside the clear aperture or back onto
    the ray's own origin on its last part passes through (``passing``)."""
    m = len(part)
    exact = np.zeros((m, 3))
    refined = np.zeros(m, bool)
    passing = np.zeros(m, bool)
    surfaces = spec.part_surfaces or ()
    for p in np.unique(part):
        surf = surfaces[p] if p < len(surfaces) else None
        if surf is None:
            continue
        g = np.flatnonzero(part == p)
        t, n_front, ok = surf.refine_hits(origin[g], d[g], distance_mm[g])
        bad = ~ok | ((last_part[g] == p) & (t < SELF_HIT_MM))
        passing[g[bad]] = True
        good = g[~bad]
        nf = n_front[~bad]
        exact[good] = origin[g[~bad]] + t[~bad, None] * d[good]
        fr = _dot(d[good], nf) < 0
        front[good] = fr
        facing[good] = np.where(fr[:, None], nf, -nf)
        refined[good] = True
    return front, facing, exact, refined, passing


def side_material(spec, part, front):
    """Material index of the side of ``part`` that was hit; a dielectric's back is its medium."""
    m_front = spec.part_material[part]
    back_idx = spec.part_back_material[part] if spec.part_back_material is not None else np.full(len(part), -1)
    return np.where(front | (back_idx < 0), m_front, back_idx)


def smooth_coefficients_into(model, g, back, cos_i, distance_mm, out):
    """Fresnel amplitudes of the rows ``g`` (all of material ``model``) into
    ``out = (r_s, r_p, t_s, t_p, cos_t, eta, bulk)`` (``Material.smooth_coefficients``); ``bulk``
    = exp(-alpha d) for a ray arriving on the back of an absorbing ``dielectric`` (d = ``distance_mm``)."""
    smooth = getattr(model, "smooth", None)
    if smooth is None:
        return
    rs, rp, ts, tp, cos_t, eta, bulk = out
    for side in (False, True):
        gg = g[back[g] == side]
        if len(gg) == 0:
            continue
        c = model.smooth_coefficients(cos_i[gg], back=side)
        rs[gg], rp[gg], ts[gg], tp[gg] = c.r_s, c.r_p, c.t_s, c.t_p
        cos_t[gg], eta[gg] = c.cos_t, c.eta
        if side and isinstance(smooth, Dielectric) and smooth.attenuation_per_mm > 0:
            bulk[gg] = np.exp(-smooth.attenuation_per_mm * distance_mm[gg])
