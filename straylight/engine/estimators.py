"""The variance-reduction strategies of the engine, listed once: what turns each on and which
interaction-kind capability (straylight.engine.interactions.registry.Capability) it needs.

With all of them off (:data:`ANALOG`) the engine is an analog random walk: every estimator must
agree with it within its standard errors, on every interaction kind; an estimator engages on a
kind's parts exactly when the kind declares its capability. tests/straylight/test_engine_contract.py
runs every kind under every estimator of :data:`ESTIMATORS` (docs/engine.md, "Capabilities"); a
new estimator is covered by adding a row here.
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields, replace

from straylight.engine.capabilities import Capability
from straylight.engine.options import EstimatorOptions

#: the estimator options of the analog walk: no NEE, no vertex sampling, no target mixture
ANALOG = EstimatorOptions(nee=False, first_vertex_sampling=False, second_vertex_sampling=False,
                          vertex_lobe_sampling=False, second_vertex_lobe_sampling=False, reflection_split=False,
                          delta_chain=0, target_parts=())


@dataclass(frozen=True)
class Estimator:
    """One strategy: its ``name``, the :class:`EstimatorOptions` that turn it on (the analog walk
    :data:`ANALOG` with its switches set), the kind ``capability`` it needs, and whether the numpy
    reference walk implements it (``reference``). ``target`` asks for the scene's flat target part
    in ``target_parts``."""

    name: str
    options: EstimatorOptions
    capability: Capability
    reference: bool = True
    target: bool = False
    requires: tuple = field(default=())  # names of estimators it runs on top of
    #: it sees edge diffraction (CONTRACTS §6.5): its shadow rays know the diffracting edges, or it only
    #: picks directions the walk then follows; a strategy without it is turned off in traces that diffract
    diffraction: bool = False

    def switches(self) -> dict:
        """The fields of :attr:`options` that differ from :data:`ANALOG` (what turns it on)."""
        return {f.name: getattr(self.options, f.name) for f in fields(EstimatorOptions)
                if getattr(self.options, f.name) != getattr(ANALOG, f.name)}


ESTIMATORS = (
    Estimator("nee", replace(ANALOG, nee=True), Capability.NEE, diffraction=True),
    Estimator("first_vertex", replace(ANALOG, first_vertex_sampling=True), Capability.FIRST_VERTEX, reference=False),
    # first-vertex sampling joined to the detector by the lobe's own draw as well
    Estimator("first_vertex_lobe", replace(ANALOG, first_vertex_sampling=True, vertex_lobe_sampling=True),
              Capability.FIRST_VERTEX, reference=False),
    Estimator("second_vertex", replace(ANALOG, nee=True, second_vertex_sampling=True), Capability.SECOND_VERTEX,
              requires=("nee",)),
    # second-vertex sampling whose critical point also leaves along its lobe's own draw
    Estimator("second_vertex_lobe",
              replace(ANALOG, nee=True, second_vertex_sampling=True, second_vertex_lobe_sampling=True),
              Capability.SECOND_VERTEX, requires=("nee",)),
    # an interface's reflection straight into a detector counted by its expected value
    Estimator("reflection_split", replace(ANALOG, reflection_split=True), Capability.REFLECTION_SPLIT),
    # runs of up to 4 interfaces into a detector (a singlet's two-reflection ghost) followed by splitting
    Estimator("delta_chain", replace(ANALOG, delta_chain=4), Capability.DELTA_CHAIN),
    # the source's entrance points drawn from a pilot-learnt density (any kind: it acts before the first hit)
    Estimator("entrance", replace(ANALOG, entrance_sampling=True), Capability.NONE, diffraction=True),
    Estimator("target_mis", replace(ANALOG, nee=True, target_fraction=0.5), Capability.TARGET_MIS, target=True,
              requires=("nee",), diffraction=True),
)


def options_for(estimator: Estimator, target_part: str | None = None) -> EstimatorOptions:
    """The analog walk's estimator options with ``estimator`` on (``target_part``: the scene's flat
    part for target sampling)."""
    if estimator.target:
        return replace(estimator.options, target_parts=(target_part,) if target_part else ())
    return estimator.options


def without_diffraction_blind(options):
    """``options`` (TraceOptions) with every strategy that does not see edge diffraction turned off
    (set back to its :data:`ANALOG` value): used when a part diffracts."""
    off = {k: getattr(ANALOG, k) for e in ESTIMATORS if not e.diffraction for k in e.switches()}
    off = {k: v for k, v in off.items() if k not in _SHARED_SWITCHES}
    changed = {k: v for k, v in off.items() if getattr(options.estimator, k) != v}
    return replace(options, estimator=replace(options.estimator, **changed)) if changed else options


#: switches that a diffraction-blind strategy turns on together with one that sees diffraction
_SHARED_SWITCHES = {k for e in ESTIMATORS if e.diffraction for k in e.switches()}
