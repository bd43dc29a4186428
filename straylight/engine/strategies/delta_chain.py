"""Runs of up to K interfaces into a detector (a singlet's two-reflection ghost; with
``delta_chain_reflections`` R, of at most R reflections) followed by splitting
(straylight.engine.delta_chain): the interfaces start and extend the runs
(``Event.states["delta_chain"]``); the walk's hits after 1..K interfaces of a run are dropped, and a
continuing hit on a part that does not split ends its run. With ``tree_split`` the glossy vertices lit by
the source send further lobe draws into the trees (straylight.engine.tree_split), with ``tree_ends`` the trees'
branch ends on glossy parts take a lobe draw of their own (straylight.engine.tree_ends), a share of them aimed
into the detectors' field through the lens, its table (straylight.engine.field_cone)."""
from __future__ import annotations

from dataclasses import replace

from straylight.engine import delta_chain as impl
from straylight.engine import field_cone, tree_ends
from straylight.engine.capabilities import Capability
from straylight.engine.tree_split import LobeSplit
from straylight.engine.strategies.base import ANALOG, BatchContext, Estimator, Strategy, TableTools


class DeltaChainStrategy(Strategy):
    estimator = Estimator("delta_chain", replace(ANALOG, delta_chain=4), Capability.DELTA_CHAIN)
    state_key = "delta_chain"
    table_field = "end_field"
    table_key = "end_field"

    def build_table(self, spec, tools: TableTools) -> object:
        est = spec.options.estimator
        if not est.tree_ends or tree_ends.unsupported(spec) is not None:
            return field_cone.FieldTable(None, "no end draws")
        return field_cone.build(spec, tools.runtime.scene(spec, tools.intersector))

    def batch_state(self, ctx: BatchContext) -> object | None:
        est = ctx.spec.options.estimator
        splits = ctx.capabilities.parts(Capability.DELTA_CHAIN)
        lobe = ends = None
        draws_ok = ctx.spec.diffraction is None and ctx.scene.target is None and splits.any()  # (the draws are the material's)
        if int(est.tree_split) > 1 and draws_ok and len(ctx.spec.sources) == 1:  # (P's density the beam's)
            lobe = LobeSplit(ctx, int(est.tree_split), splits)
        if est.tree_ends and draws_ok and tree_ends.unsupported(ctx.spec) is None:
            ends = tree_ends.TreeEnds(ctx)
        return impl.DeltaChains(ctx.n_rays, int(est.delta_chain), splits,
                                max_reflections=int(est.delta_chain_reflections), lobe_split=lobe, ends=ends)

    def after_interactions(self, state, event, continuing, outgoing) -> None:
        if state.lobe_split is not None and len(continuing):
            state.lobe_split.at_vertices(event, state, continuing, outgoing)

    def at_interfaces(self, state, event, interfaces) -> None:
        state.at_interfaces(event, interfaces)

    def share_walk_hits(self, state, event, rec, rec_w):
        return state.share_after_chain(event, rec, rec_w)

    def after_hits(self, state, event, continuing) -> None:
        state.leave_run(event, continuing[~state.splits[event.hits.part[continuing]]])


DELTA_CHAIN = DeltaChainStrategy()
