"""Reverse chains (straylight.engine.reverse_chain): per ray an eye chain from a detector through up to K
interfaces to a plain scatter point P, joined to the source and to the walk's scatter vertices; the
walk's own such paths (and split trees or reflection splits after P) are dropped. Off where the eye
pilot finds their family carries too little of the light (:class:`~straylight.engine.reverse_chain.EyesOff`)."""
from __future__ import annotations

from dataclasses import replace

from straylight.engine import reverse_chain as impl
from straylight.engine.capabilities import Capability
from straylight.engine.strategies.base import ANALOG, BatchContext, Estimator, Strategy, TableTools

#: the key of ``TableTools.measured`` where the entrance pilot leaves the eye table it had built (straylight.engine.
#: strategies.entrance: mid-pilot, for the rest of its pilot)
EYE_TABLE = "eye_table"


class ReverseChainStrategy(Strategy):
    estimator = Estimator("reverse_chain", replace(ANALOG, reverse_chain=4), Capability.DELTA_CHAIN, reference=False)
    state_key = "reverse_chain"
    table_field = "eye_table"
    table_key = "eye"

    @property
    def needs_table(self) -> str | None:
        return None  # without a table (a pilot that joined nothing) the eye directions stay cosine

    def build_table(self, spec, tools: TableTools) -> object:
        # the entrance pilot (built before) leaves its detected power: the eye pilot weighs its chains' share of
        # the light by it (None: the chains run); where its rest ran the chains, it built this table itself
        measured = tools.measured or {}
        if EYE_TABLE in measured:  # built by the entrance pilot, after its first stage
            return measured[EYE_TABLE]
        return impl.build_table(spec, tools.runtime.scene(spec, tools.intersector), detected_w=measured.get("detected_w"))

    def declines(self, spec) -> str | None:
        table = spec.eye_table
        return table.reason if isinstance(table, impl.EyesOff) else None

    def rules_out(self, spec, intersector) -> str | None:
        return impl.unsupported(spec)

    def batch_state(self, ctx: BatchContext) -> object | None:
        est = ctx.spec.options.estimator
        # a split tree after an end point is left to the chains: they must reach as far as the tree would
        k = max(int(est.reverse_chain), int(est.delta_chain))
        return impl.ReverseChains(ctx, k, ctx.capabilities.parts(Capability.DELTA_CHAIN))

    def share_walk_hits(self, state, event, rec, rec_w):
        return state.share_walk_hits(event, rec, rec_w)

    def after_hits(self, state, event, continuing) -> None:
        state.after_hits(event, continuing)

    def after_interactions(self, state, event, continuing, outgoing) -> None:
        state.after_interactions(event, continuing, outgoing)

    def after_walk(self, state, ctx: BatchContext) -> int:
        state.check_joined()
        return state.shadow_rays


REVERSE_CHAIN = ReverseChainStrategy()
