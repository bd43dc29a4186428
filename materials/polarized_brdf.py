"""The Mueller-matrix BRDF of a material, as far as its models define it (CONTRACTS §6.3).

``mueller_brdf(model, wi, wo, s_in)`` returns M (n, 4, 4) in 1/sr, from the incident s/p basis
(s_in, p_in = k_i x s_in; k_i = -wi) to the scattered basis (e1 = wo x z normalised, e2 = wo x e1;
e1 = s_in for scatter along the normal),
summed over the model's scatter components:

- ``k_correlation`` with a substrate index ``n``: the full matrix, ``f_u`` times the normalised
  Mueller matrix of the Rayleigh-Rice Jones matrix (:mod:`materials.rayleigh_rice`): it polarizes
  unpolarized light, turns linear into elliptical light out of the plane of incidence, and reads
  S2 and S3 of the incident light (the cross terms);
- every other component (Lambertian, ABg, Harvey-Shack, microfacet, particulate, tabulated,
  k_correlation with a constant ``r``): only the first row the model defines through its s and p
  BRDFs, ``M00 = (f_s + f_p)/2``, ``M01 = (f_s - f_p)/2``; the other elements are taken as 0 (the
  scattered light is unpolarized: exact for a Lambertian diffuser, an assumption for the others).

The sum of physical Mueller matrices is physical, so the degree of polarization of ``M S`` never
exceeds 1. For unpolarized light ``M00`` equals the model's unpolarized BRDF.
"""
from __future__ import annotations

import numpy as np

from materials.base import PairGeometry, directions_from_angles
from materials.kcorrelation import KCorrelation
from materials.rayleigh_rice import add_rayleigh_rice_mueller, s_basis

_PROBE = None


def components_of(model) -> tuple:
    """The scatter components of a material, a composite or a single model."""
    if hasattr(model, "lobes"):
        return tuple(model.lobes)
    comps = getattr(model, "components", None)
    return tuple(comps) if comps is not None else (model,)


def _full(comp) -> bool:
    return isinstance(comp, KCorrelation) and comp.n is not None


def _probe():
    global _PROBE
    if _PROBE is None:
        ti, tr, pr = np.meshgrid(np.deg2rad([10.0, 45.0, 75.0]), np.deg2rad([5.0, 40.0, 70.0]),
                                 np.deg2rad([0.0, 60.0, 180.0]), indexing="ij")
        _PROBE = directions_from_angles(ti.ravel(), tr.ravel(), pr.ravel())
    return _PROBE


def is_polarizing(model) -> bool:
    """Whether the model's scatter depends on or changes the polarization: a component with the full
    matrix, or one whose s and p BRDFs differ on a probe grid. Cached on the model."""
    cached = getattr(model, "_polarizing_cache", None)
    if cached is not None:
        return cached
    wi, wo = _probe()
    value = False
    for c in components_of(model):
        if _full(c) or not np.allclose(c.brdf(wi, wo, "s"), c.brdf(wi, wo, "p"), rtol=1e-12, atol=0.0):
            value = True
            break
    try:
        object.__setattr__(model, "_polarizing_cache", value)
    except (AttributeError, TypeError):
        pass
    return value


def mueller_brdf(model, wi, wo, s_in=None, first_row_only: bool = False):
    """``(M (n, 4, 4) in 1/sr, e1_out (n, 3))`` for local directions wi, wo (n, 3) (z the normal)
    and the incident s vectors ``s_in`` (n, 3; default k_i x z normalised). ``first_row_only``: row 0
    alone (what the scattered power ``M[0] . S`` needs), rows 1-3 zero; row 0 is the same either way."""
    wi = np.asarray(wi, float)
    wo = np.asarray(wo, float)
    s_in = s_basis(-wi) if s_in is None else np.asarray(s_in, float)
    e1 = s_basis(wo, fallback=s_in)
    M = np.zeros((len(wi), 4, 4))
    comps = components_of(model)
    pair = PairGeometry(wi, wo)
    k = 0
    while k < len(comps):
        c = comps[k]
        if _full(c):  # a run of full components of one substrate index: its normalised matrix once
            run = [c]
            while k + len(run) < len(comps) and _full(comps[k + len(run)]) and comps[k + len(run)]._index == c._index:
                run.append(comps[k + len(run)])
            F = np.array([r.brdf(wi, wo, "u", pair=pair) for r in run])  # the lobes share azimuth and factor
            add_rayleigh_rice_mueller(M, F, wi, wo, c._index, s_in, e1, first_row_only)  # M += f Mn, in order
            k += len(run)
            continue
        fs = c.brdf(wi, wo, "s")
        fp = c.brdf(wi, wo, "p")
        M[:, 0, 0] += 0.5 * (fs + fp)
        M[:, 0, 1] += 0.5 * (fs - fp)
        k += 1
    return M, e1
