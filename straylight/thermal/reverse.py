"""Reverse (adjoint) thermal estimator: rays leave the detector's front and pick up emission at
every vertex, as FRED does.

By reciprocity the band power a detector of front area A receives is P = A pi E[L], with L the
radiance arriving along a cosine-distributed direction from a uniform point of the front. Along
the reverse path y_1, y_2, ... (each vertex reached with throughput w_k, w_1 = 1)::

    L = sum_k w_k epsilon_{j_k}(theta_k) B_band(T_{j_k})

where theta_k is the angle of the path at y_k on the side of part j_k it meets (Kirchhoff: the
emitted radiance there is epsilon(theta) B with that side's epsilon; the front of every part, and
the back of a one-sided part: model.ThermalScene.one_sided), and w_{k+1} = w_k f cos / pdf from the material's
own sampling (swapped arguments: exact for reciprocal BRDFs). The pickup is the expected emission,
not a sampled one, so a black wall's contribution has no variance at all. Absorbers and detectors
(epsilon = 1) end the path; a path that comes back to the detector picks up the detector's own
emission (narcissus).
"""
from __future__ import annotations

import numpy as np

from straylight.thermal.sampling import AreaSampler, cosine_directions
from straylight.thermal.walk import walk


def reverse_batch(ts, sides, det_sampler: AreaSampler, radiance: np.ndarray, draws):
    """The reverse rays of one batch of whole chunks (``draws``: straylight.rng.BatchDraws, each ray
    drawing from its chunk's stream). ``radiance`` (P,): B_band of each part's temperature in this
    sub-band (W m^-2 sr^-1), or (C, P) for C temperature sets traced together (the paths do not
    depend on temperatures). Returns the per-ray power estimates A pi L in W (areas in mm^2 -> m^2):
    per part (P, n) for the first set, and the totals (C, n) of every set."""
    n = draws.n_rays
    P = ts.n_parts
    u = draws.all(5)
    o, nrm = det_sampler.sample(u[:, :3])
    d = cosine_directions(nrm, u[:, 3:5])
    pick = np.zeros(P * n)  # per (part, ray) radiance pickups per unit B
    emits = ts.temperature_k > 0

    def pickup(ev):  # the expected emission of the side met: w epsilon(theta)
        hit = ev.hit
        alive = ev.alive
        part = hit.part
        front = alive & hit.front
        safe = np.where(alive, part, 0)
        take = alive & emits[safe] & (front | ts.one_sided[safe])
        if take.any():
            e = sides.emissivity(part[take], np.where(front[take], 0, 1), hit.theta[take])
            np.add.at(pick, part[take] * n + ev.ray[take], ev.w[take] * e)

    walk(ts, sides, draws, o, nrm, d, np.ones(n), pickup)
    scale = det_sampler.area_mm2 * 1e-6 * np.pi
    per = pick.reshape(P, n) * scale
    rad = np.atleast_2d(radiance)
    return per * rad[0][:, None], rad @ per
