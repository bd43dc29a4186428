"""Integrals over the forward model's quadrature nodes, cached per component (used by the fit's
materials in rig.diagnose and by effects that add a lobe, e.g. rig.effects.substrate_reflection)."""
from __future__ import annotations

import numpy as np


def cached_integral(geom, weight, key, make):
    """sum over nodes of weight * make() per point, cached in ``geom`` under ``key``.

    ``weight`` is (n_points, n_nodes); ``make()`` returns the integrand, (n_points, n_nodes)
    or flat.
    Each component's integral is cached separately, so changing one lobe (or only an
    amplitude) re-integrates only that lobe (or nothing)."""
    cache = geom["int_cache"]
    out = cache.get(key)
    if out is None:
        if len(cache) > 64:
            cache.clear()
        out = np.einsum("nk,nk->n", weight, make().reshape(weight.shape))
        cache[key] = out
    return out
