"""The estimator sets the analyses trace with (pst, paths, study, design sweeps).

``default``
    next-event estimation, first-vertex sampling with the lobe's own draw
    (``vertex_lobe_sampling``, issue 26) and second-vertex sampling with the lobe's own draw at its
    critical point (``second_vertex_lobe_sampling``, issue 26).
``first_lobe``
    the default without the second-vertex lobe draw (to measure what each one buys).
``baseline``
    the set before issue 26 (first-vertex sampling joined to the detector by a uniform point
    only), kept so benchmarks can time before and after in one run (``--estimators baseline``).
"""
from __future__ import annotations

from dataclasses import replace

ESTIMATOR_SETS = {
    "default": {"first_vertex_sampling": True, "second_vertex_sampling": True, "vertex_lobe_sampling": True,
                "second_vertex_lobe_sampling": True},
    "first_lobe": {"first_vertex_sampling": True, "second_vertex_sampling": True, "vertex_lobe_sampling": True,
                   "second_vertex_lobe_sampling": False},
    "baseline": {"first_vertex_sampling": True, "second_vertex_sampling": True, "vertex_lobe_sampling": False,
                 "second_vertex_lobe_sampling": False},
}


def estimator_options(name: str = "default", options=None):
    """``options`` (default ``TraceOptions()``) with the estimator set ``name`` switched on."""
    from straylight.trace import TraceOptions

    if name not in ESTIMATOR_SETS:
        raise ValueError(f"unknown estimator set {name!r}; known: {', '.join(ESTIMATOR_SETS)}")
    return replace(options or TraceOptions(), **ESTIMATOR_SETS[name])
