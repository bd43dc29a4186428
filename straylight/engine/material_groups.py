"""Per-material dispatch, written once: materials are called through their Python API
(``brdf``, ``pdf``, ``sample``) once per material on contiguous arrays."""
from __future__ import annotations

import numpy as np


def by_material(models, material_index, call):
    """Evaluate ``call(model, rows)`` per material over the rows of ``material_index`` (material per
    row); returns the list of (rows, result); rows is a slice when one material covers everything."""
    if len(models) == 1:
        return [(slice(None), call(models[0], slice(None)))]
    out = []
    for m in np.unique(material_index):
        sel = np.flatnonzero(material_index == m)
        out.append((sel, call(models[m], sel)))
    return out
