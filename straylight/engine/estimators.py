"""The declarations of the variance-reduction strategies (straylight.engine.strategies), as one table:
:data:`ESTIMATORS`, one :class:`Estimator` row per strategy of
:data:`straylight.engine.strategies.registry.STRATEGIES`, in its order (what turns each on and which
interaction-kind capability, straylight.engine.capabilities.Capability, it needs).

With all of them off (:data:`ANALOG`) the engine is an analog random walk: every estimator must
agree with it within its standard errors, on every interaction kind; an estimator engages on a
kind's parts exactly when the kind declares its capability. tests/straylight/test_engine_contract.py
runs every kind under every estimator of :data:`ESTIMATORS` (docs/engine.md, "Strategies").
"""
from __future__ import annotations

from dataclasses import replace

from straylight.engine.options import EstimatorOptions
from straylight.engine.strategies.base import ANALOG, Estimator
from straylight.engine.strategies.registry import STRATEGIES

__all__ = ["ANALOG", "ESTIMATORS", "Estimator", "options_for", "without_diffraction_blind"]

ESTIMATORS: tuple[Estimator, ...] = tuple(s.estimator for s in STRATEGIES)


def options_for(estimator: Estimator, target_part: str | None = None) -> EstimatorOptions:
    """The analog walk's estimator options with ``estimator`` on (``target_part``: the scene's flat
    part for target sampling)."""
    if estimator.target:
        return replace(estimator.options, target_parts=(target_part,) if target_part else ())
    return estimator.options


def without_diffraction_blind(options):
    """``options`` (TraceOptions) with every strategy that does not see edge diffraction turned off
    (set back to its :data:`ANALOG` value): used when a part diffracts (first- and second-vertex
    sampling join vertices by straight shadow rays that do not know the edges; NEE, target MIS and the
    walk see every path)."""
    off = {k: getattr(ANALOG, k) for e in ESTIMATORS if not e.diffraction for k in e.switches()}
    off = {k: v for k, v in off.items() if k not in _SHARED_SWITCHES}
    changed = {k: v for k, v in off.items() if getattr(options.estimator, k) != v}
    return replace(options, estimator=replace(options.estimator, **changed)) if changed else options


#: switches that a diffraction-blind strategy turns on together with one that sees diffraction
_SHARED_SWITCHES = {k for e in ESTIMATORS if e.diffraction for k in e.switches()}
