"""An interface's reflection straight into a detector counted by its expected value
(straylight.engine.reflection_split): the interfaces call it (``Event.states["reflection_split"]``), and
the walk's own hits straight after such a reflection are dropped."""
from __future__ import annotations

from dataclasses import replace

from straylight.engine import reflection_split as impl
from straylight.engine.capabilities import Capability
from straylight.engine.strategies.base import ANALOG, BatchContext, Estimator, Strategy


class ReflectionSplitStrategy(Strategy):
    estimator = Estimator("reflection_split", replace(ANALOG, reflection_split=True), Capability.REFLECTION_SPLIT)
    state_key = "reflection_split"

    def batch_state(self, ctx: BatchContext) -> object | None:
        return impl.ReflectionSplit(ctx.n_rays)

    def at_interfaces(self, state, event, interfaces) -> None:
        state.at_interfaces(event, interfaces)

    def share_walk_hits(self, state, event, rec, rec_w):
        return state.share_after_reflection(event, rec, rec_w)


REFLECTION_SPLIT = ReflectionSplitStrategy()
