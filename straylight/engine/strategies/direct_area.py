"""The unscattered light, exactly (straylight.engine.direct_area): where one collimated beam reaches a flat
mesh detector straight, by 2-D clipping along the beam; every ray carries its share of that power and the
walk's hits on the detector at its first event are dropped. Off where no detector point sees the beam
straight (:class:`~straylight.engine.direct_area.Declined`)."""
from __future__ import annotations

from dataclasses import replace

from straylight.engine import direct_area as impl
from straylight.engine.capabilities import Capability
from straylight.engine.strategies.base import ANALOG, BatchContext, Estimator, Strategy, TableTools


class DirectArea(Strategy):
    # it acts before any hit, on no kind's parts; it does not see diffracting edges (the beam bends there)
    estimator = Estimator("direct_area", replace(ANALOG, direct_area=True), Capability.NONE, reference=False)
    table_field = "direct_table"
    table_key = "direct"
    state_key = "direct_area"

    def rules_out(self, spec, intersector) -> str | None:
        return impl.unsupported(spec)

    def build_table(self, spec, tools: TableTools) -> object:
        return impl.build(spec)

    def declines(self, spec) -> str | None:
        table = spec.direct_table
        return table.reason if isinstance(table, impl.Declined) else None

    def batch_state(self, ctx: BatchContext) -> object | None:
        return impl.DirectShares(ctx, ctx.spec.direct_table)

    def share_walk_hits(self, state, event, rec, rec_w):
        return state.share_walk_hits(event, rec, rec_w)

    def after_hits(self, state, event, continuing) -> None:
        state.after_hits(event, continuing)


DIRECT_AREA = DirectArea()
