"""Per-material dispatch, written once: materials are called through their Python API
(``brdf``, ``pdf``, ``sample``) once per material on contiguous arrays."""
from __future__ import annotations

import numpy as np


def distinct(index) -> np.ndarray:
    """The distinct values of an integer array, ascending: ``np.unique``'s, found by counting when
    none is negative (no sort: the groups of materials, parts and detectors are few, the rows many;
    -1, e.g. no material, goes through ``np.unique``)."""
    index = np.asarray(index)
    if index.size == 0 or index.min() < 0:
        return np.unique(index)
    return np.flatnonzero(np.bincount(index.ravel()))


def by_material(models, material_index, call):
    """Evaluate ``call(model, rows)`` per material over the rows of ``material_index`` (material per
    row); returns the list of (rows, result); rows is a slice when one material covers everything."""
    if len(models) == 1:
        return [(slice(None), call(models[0], slice(None)))]
    out = []
    for m in distinct(material_index):
        sel = np.flatnonzero(material_index == m)
        out.append((sel, call(models[m], sel)))
    return out


def brdf_and_pdf(model, wi, wo, polarization: str):
    """``(model.brdf(wi, wo), model.pdf(wi, wo))`` in one call where the model shares their common
    quantities (``brdf_pdf``, materials.material.Material: the same bits), else the two calls."""
    both = getattr(model, "brdf_pdf", None)
    if both is not None:
        return both(wi, wo, polarization)
    return model.brdf(wi, wo, polarization), model.pdf(wi, wo, polarization)
