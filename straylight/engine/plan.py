"""Which of the requested strategies run on one trace, decided once (docs/engine.md, "Strategy plan").

A strategy (a row of :data:`straylight.engine.estimators.ESTIMATORS`) is *requested* when every
switch it sets is on in the options the caller gave; it *runs* unless the scene or the sources rule
it out, and then the plan says why in one line instead of dropping it silently:

- a part diffracts and the strategy does not see diffracting edges (its straight shadow rays or
  vertex links do not know them);
- there is no detector part (every strategy but the walk connects to a detector);
- first-vertex sampling under a caller's own intersector (its table is built on embree);
- second-vertex sampling on polarized light (:func:`straylight.engine.second_vertex.unsupported`);
- entrance sampling with more than one source (its table is over one source's uniforms).

:func:`straylight.trace.trace` builds its tables from :meth:`StrategyPlan.runs` and returns the plan
with its result (``TraceResult.strategies``; ``straylight trace --json`` writes it as
``strategies``). The kinds' per-part capabilities (which parts NEE or the chains act on) stay with
the kinds (straylight.engine.interactions).
"""
from __future__ import annotations

from dataclasses import dataclass

from straylight.engine import entrance_sampling
from straylight.engine.estimators import ESTIMATORS, Estimator
from straylight.engine.second_vertex import unsupported as second_vertex_unsupported


@dataclass(frozen=True)
class StrategyPlan:
    """``on``: the requested strategies that run; ``off``: (name, why) of those that do not."""

    on: tuple[str, ...]
    off: tuple[tuple[str, str], ...]

    def runs(self, name: str) -> bool:
        return name in self.on

    def to_dict(self) -> dict:
        return {"on": list(self.on), "off": {name: why for name, why in self.off}}

    def notes(self) -> list[str]:
        """One line per strategy that was asked for and does not run."""
        return [f"{name} off: {why}" for name, why in self.off]


def requested(estimator: Estimator, options) -> bool:
    """Are all of ``estimator``'s switches on in ``options`` (EstimatorOptions)? Target sampling is
    requested by naming target parts."""
    if estimator.target:
        return bool(options.target_parts) and bool(options.nee)
    switches = estimator.switches()
    return bool(switches) and all(_on(getattr(options, k), v) for k, v in switches.items())


def _on(value, wanted) -> bool:
    if isinstance(wanted, bool):
        return bool(value) == wanted
    if isinstance(wanted, (int, float)) and not isinstance(wanted, bool):
        return bool(value)  # a count (delta_chain = K) or a fraction: on when non-zero
    return value == wanted


def resolve(requested_options, spec, intersector=None) -> StrategyPlan:
    """The plan for ``spec`` (built by :func:`straylight.engine.spec.make_spec` from
    ``requested_options``, the caller's TraceOptions) traced with ``intersector`` (None: embree)."""
    asked = requested_options.estimator
    diffracts = spec.diffraction is not None
    detectors = len(spec.detector_parts) > 0
    on: list[str] = []
    off: list[tuple[str, str]] = []
    for est in ESTIMATORS:
        if not requested(est, asked):
            continue
        why = None
        if diffracts and not est.diffraction:
            why = "a part diffracts and this strategy's links do not see diffracting edges"
        elif not detectors and est.name != "entrance":
            why = "the scene has no detector part"
        elif est.name.startswith("first_vertex") and intersector is not None:
            why = "its table is built on embree, and this trace has its own intersector"
        elif est.name.startswith("second_vertex"):
            why = second_vertex_unsupported(spec)
        elif est.name == "entrance" and not entrance_sampling.applies(spec):
            why = "it needs exactly one source and a detector part"
        if why is None:
            on.append(est.name)
        else:
            off.append((est.name, why))
    return StrategyPlan(tuple(on), tuple(off))

