"""Which of the requested strategies run on one trace, decided once (docs/engine.md, "Strategies").

A strategy (straylight.engine.strategies.registry.STRATEGIES) is *requested* when every switch it sets
is on in the options the caller gave; it *runs* unless the scene or the sources rule it out, and then
the plan says why in one line instead of dropping it silently. The plan asks, in order:

- its declaration: a part diffracts and the strategy does not see diffracting edges
  (``Estimator.diffraction``: its straight shadow rays or vertex links do not know them); there is no
  detector part and it connects to one (``Strategy.needs_detector``);
- the strategy itself (:meth:`Strategy.rules_out <straylight.engine.strategies.base.Strategy.rules_out>`:
  first-vertex sampling under a caller's own intersector, second-vertex sampling on polarized light,
  entrance sampling with more than one source, ...).

:func:`straylight.trace.trace` builds the tables of :meth:`StrategyPlan.runs` (:func:`build_tables`),
turns off the strategies whose tables say they do not pay (:func:`without_declined`: the eye chains
where their pilot finds their family carries too little of the light), puts the names that run on the spec (``TraceSpec.strategies_on``: the walk builds states for those
only, :func:`running`) and returns the plan with its result (``TraceResult.strategies``;
``straylight trace --json`` writes it as ``strategies``). The kinds' per-part capabilities (which parts NEE or the chains act on) stay with
the kinds (straylight.engine.interactions).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

from straylight.engine.strategies.base import Estimator, Strategy
from straylight.engine.strategies import registry


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


def why_off(strategy: Strategy, spec, intersector=None) -> str | None:
    """Why ``strategy`` cannot run on ``spec`` traced with ``intersector``: its declared flags first,
    then its own :meth:`~straylight.engine.strategies.base.Strategy.rules_out`; None when it can."""
    if spec.diffraction is not None and not strategy.estimator.diffraction:
        return "a part diffracts and this strategy's links do not see diffracting edges"
    if strategy.needs_detector and len(spec.detector_parts) == 0:
        return "the scene has no detector part"
    return strategy.rules_out(spec, intersector)


def resolve(requested_options, spec, intersector=None) -> StrategyPlan:
    """The plan for ``spec`` (built by :func:`straylight.engine.spec.make_spec` from
    ``requested_options``, the caller's TraceOptions) traced with ``intersector`` (None: embree)."""
    asked = requested_options.estimator
    on: list[str] = []
    off: list[tuple[str, str]] = []
    for strategy in registry.STRATEGIES:
        if not requested(strategy.estimator, asked):
            continue
        why = why_off(strategy, spec, intersector)
        if why is None:
            on.append(strategy.name)
        else:
            off.append((strategy.name, why))
    return StrategyPlan(tuple(on), tuple(off))


def without_missing_tables(plan: StrategyPlan, spec, why: str) -> StrategyPlan:
    """``plan`` with each strategy that runs but whose table (Strategy.needs_table) ``spec`` lacks turned
    off for ``why``."""
    missing = [name for name in plan.on if _table_missing(registry.BY_NAME.get(name), spec)]
    if not missing:
        return plan
    return StrategyPlan(tuple(n for n in plan.on if n not in missing), plan.off + tuple((n, why) for n in missing))


def without_declined(plan: StrategyPlan, spec) -> StrategyPlan:
    """``plan`` with each strategy that runs but declines on ``spec`` (its table built:
    :meth:`Strategy.declines <straylight.engine.strategies.base.Strategy.declines>`) turned off for its
    reason."""
    why = {name: registry.BY_NAME[name].declines(spec) for name in plan.on if name in registry.BY_NAME}
    out = [(n, w) for n, w in why.items() if w is not None]
    if not out:
        return plan
    return StrategyPlan(tuple(n for n in plan.on if why.get(n) is None), plan.off + tuple(out))


def _table_missing(strategy: Strategy | None, spec) -> bool:
    field = None if strategy is None else strategy.needs_table
    return field is not None and getattr(spec, field) is None


def build_tables(spec, plan: StrategyPlan, tools, cache: bool = True):
    """``spec`` with the tables of the strategies ``plan`` runs, built by their own
    :meth:`~straylight.engine.strategies.base.Strategy.build_table` with ``tools`` (TableTools) in registry
    order (each sees the ones before it: the entrance pilot runs with them); kept in the runtime's table
    cache (``tools.runtime.table``) when ``cache``."""
    tools = tools._replace(plan=plan)
    for strategy in registry.STRATEGIES:
        if strategy.table_field is None or not plan.runs(strategy.name):
            continue
        table = tools.runtime.table(strategy.table_key, spec, lambda s=strategy, sp=spec: s.build_table(sp, tools),
                                    cache=cache)
        spec = replace(spec, **{str(strategy.table_field): table})
    return spec


def running(spec, intersector=None) -> tuple[str, ...]:
    """The names of the strategies the walk runs on ``spec`` (traced with ``intersector``): the plan's
    (``spec.strategies_on``, set by :func:`straylight.trace.trace`); for a spec without one (make_spec
    and a direct ``run_batch``) the plan resolved here from the spec's options, without the strategies
    whose tables were not built and those that decline (:func:`without_declined`)."""
    if spec.strategies_on is not None:
        return tuple(spec.strategies_on)
    plan = without_missing_tables(resolve(spec.options, spec, intersector), spec, "its table was not built")
    return without_declined(plan, spec).on
