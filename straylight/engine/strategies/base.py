"""What a strategy is (docs/engine.md, "Strategies"): :class:`Estimator`, its declaration (name, the
switches that turn it on, the interaction-kind capability it needs, flags), and :class:`Strategy`,
the declaration with the hooks the rest of the engine calls:

- :meth:`Strategy.rules_out` (straylight.engine.plan): why it cannot run on this trace, in one line;
- :meth:`Strategy.build_table` (straylight.trace): the table it learns before the walk, stored on the
  spec in :attr:`Strategy.table_field`; then :meth:`Strategy.declines` (straylight.engine.plan): its
  table built, whether it does not pay on this trace (the plan turns it off and says why);
- :meth:`Strategy.batch_state` and the walk hooks (straylight.engine.walk): its per-batch state, handed
  to the interactions on ``Event.states`` under :attr:`Strategy.state_key`, and what it does at fixed
  points of each event (:meth:`~Strategy.share_walk_hits`, :meth:`~Strategy.after_hits`) and after the
  batch's last event (:meth:`~Strategy.after_walk`);
- the hooks of the interaction kinds: weights of the scatter vertices (:meth:`~Strategy.vertex_weights`,
  called through ``Event.vertex_weights``) and what it does at Fresnel interfaces
  (:meth:`~Strategy.at_interfaces`, called by the interface kind where it allows the strategy's
  capability; the walk hands them ``Event.vertex_hooks`` and ``Event.interface_hooks``);
- the hooks of next-event estimation (straylight.engine.nee, handed them by the walk on
  ``Event.nee_hooks``): weights of the vertices' NEE (:meth:`~Strategy.nee_weights`), the walk's direction
  density NEE weighs against (:meth:`~Strategy.nee_density`), and what runs after NEE from the same
  vertices (:meth:`~Strategy.after_nee`). NEE itself imports no other strategy.

Every hook has a do-nothing default: a strategy overrides the ones it needs.
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any, ClassVar, NamedTuple

from straylight.engine.capabilities import Capability
from straylight.engine.options import EstimatorOptions

#: the estimator options of the analog walk: no NEE, no vertex sampling, no target mixture
ANALOG = EstimatorOptions(nee=False, first_vertex_sampling=False, second_vertex_sampling=False,
                          vertex_lobe_sampling=False, second_vertex_lobe_sampling=False, reflection_split=False,
                          delta_chain=0, target_parts=())


@dataclass(frozen=True)
class Estimator:
    """One strategy's declaration: its ``name``, the :class:`EstimatorOptions` that turn it on (the
    analog walk :data:`ANALOG` with its switches set), the kind ``capability`` it needs, and whether
    the numpy reference walk implements it (``reference``). ``target`` asks for the scene's flat
    target part in ``target_parts``."""

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


class TableTools(NamedTuple):
    """What :meth:`Strategy.build_table` may use: this process's ``runtime``
    (straylight.engine.runtime.Runtime: ``runtime.scene(spec, intersector)``), the trace's ``intersector``
    (None: embree) and the compiled walk ``run_batch`` (for pilot traces; passed in, since the walk
    imports the strategies), and ``measured``: a dict where a table's pilot leaves what it measured for
    the tables after it (``"detected_w"``: the entrance pilot's estimate of the power on the detectors,
    W, straylight.engine.strategies.entrance; None: nothing is kept), and ``plan``: the StrategyPlan the tables
    are built for (set by straylight.engine.plan.build_tables; None: not known)."""

    runtime: Any
    intersector: Any
    run_batch: Any
    measured: Any = None
    plan: Any = None


class BatchContext(NamedTuple):
    """What the walk builds a strategy's per-batch state from (straylight.engine.walk.walk)."""

    spec: Any  # TraceSpec
    scene: Any  # CompiledScene
    n_rays: int  # rays in the batch
    start_weight_w: float  # total power / n_rays
    tallies: Any  # the batch's tally store
    rows: Any  # TallyRows
    records: Any  # DetectorRecords
    capabilities: Any  # PartCapabilities of the parts
    first_chunk: int
    stop_chunk: int


class Strategy:
    """One variance-reduction strategy: its declaration (:attr:`estimator`) and its hooks. Subclasses set
    the class attributes and override the hooks they need; the defaults do nothing."""

    estimator: ClassVar[Estimator]
    #: it connects to a detector (False: it acts before any detector is involved, e.g. at emission)
    needs_detector: ClassVar[bool] = True
    #: the TraceSpec field its table goes to (None: it has no table), and its key in the runtime's cache
    table_field: ClassVar[str | None] = None
    table_key: ClassVar[str] = ""
    #: on dask, the workers start building their scenes while this process builds the table (a long build)
    table_ships_early: ClassVar[bool] = False
    #: the TraceSpec field of a table it reads that another strategy builds (a lobe variant reads its
    #: base's); None: only its own :attr:`table_field`, if any
    table_from: ClassVar[str | None] = None
    #: the key of its per-batch state on ``Event.states`` (None: it has no per-batch state)
    state_key: ClassVar[str | None] = None
    #: its per-batch state reshapes emission (``emit_batch(..., on_uniforms=state)``, start weights
    #: ``state.weights``); at most one strategy of a trace may
    shapes_emission: ClassVar[bool] = False

    @property
    def name(self) -> str:
        return self.estimator.name

    def __repr__(self) -> str:
        return f"<strategy {self.name}>"

    @property
    def needs_table(self) -> str | None:
        """The TraceSpec field of the table it cannot run without (its own or the one it reads), or None."""
        return self.table_from or self.table_field

    # ------------------------------------------------------------------ the plan and the tables

    def rules_out(self, spec, intersector) -> str | None:
        """Why it cannot run on ``spec`` traced with ``intersector`` (None: embree), in one line; None
        when it can. The plan checks the declared flags first (diffraction, a detector part)."""
        return None

    def build_table(self, spec, tools: TableTools) -> object:
        """Its table for ``spec`` (only called when :attr:`table_field` is set and the plan runs it)."""
        raise NotImplementedError(f"{self.name} declares no table")

    def declines(self, spec) -> str | None:
        """After the tables: why it does not pay on ``spec`` (its table says so), in one line; None when it
        runs. The plan turns it off for that reason (:func:`straylight.engine.plan.without_declined`); the
        estimate stays unbiased: the walk counts what it would have."""
        return None

    # ------------------------------------------------------------------ the walk

    def batch_state(self, ctx: BatchContext) -> object | None:
        """Its state for one batch of the walk (None: it does nothing in this batch). Called only when the
        plan runs it (``TraceSpec.strategies_on``): what :meth:`rules_out` and the plan decided, and its
        table, need no second check here."""
        return None

    def uniform_columns(self, spec) -> int:
        """The uniforms per live ray and event it draws (read at ``event.columns.of(name)``): appended to
        the event's columns (straylight.engine.draws.event_columns) when it runs in the batch."""
        return 0

    def share_walk_hits(self, state, event, rec, rec_w):
        """The walk's detector hits ``rec`` (rows of the event, weights ``rec_w``) that this strategy
        also counts keep only their share (the rest to the NEE exchange); returns those still counted."""
        return rec, rec_w

    def after_hits(self, state, event, continuing) -> None:
        """Called once per event after the hit stage with the continuing hits (rows of the event)."""

    def after_interactions(self, state, event, continuing, outgoing) -> None:
        """Called once per event after the interactions: ``outgoing`` (straylight.engine.event.Outgoing)
        says what each continuing hit (rows of the event) did."""

    def after_walk(self, state, ctx: BatchContext) -> int:
        """Called once after the batch's last event; returns the shadow rays it cast."""
        return 0

    # ------------------------------------------------------------------ the interaction kinds

    def vertex_weights(self, state, event, verts, w_vertex):
        """MIS weights of the scatter vertices ``verts`` (rows of the event) given those so far (None: all
        1), when it also samples such vertices (first-vertex sampling)."""
        return w_vertex

    def at_interfaces(self, state, event, interfaces) -> None:
        """At the Fresnel interface hits ``interfaces`` (straylight.engine.event.Interfaces) of a kind that
        allows its capability, before the walk's branch is applied."""

    # ------------------------------------------------------------------ next-event estimation

    def nee_weights(self, state, event, verts, w_vertex):
        """Before NEE from the scatter vertices ``verts`` (rows of the event): the per-vertex factors of
        their contributions, given those so far (``w_vertex``, None: all 1)."""
        return w_vertex

    def nee_density(self, state, event, verts):
        """If it changes the walk's direction density at ``verts``: ``mix(pdf, vertex, dirs)`` turning the
        BRDF densities of directions ``dirs`` at ``verts[vertex]`` into the walk's; else None."""
        return None

    def after_nee(self, state, event, verts, frame) -> None:
        """After NEE from the scatter vertices ``verts`` (local frames ``frame``)."""


NEE_HOOKS = ("nee_weights", "nee_density", "after_nee")


def overrides(strategy: Strategy, hook: str) -> bool:
    """Whether ``strategy`` implements the hook ``hook`` (a method of :class:`Strategy`)."""
    return getattr(type(strategy), hook) is not getattr(Strategy, hook)
