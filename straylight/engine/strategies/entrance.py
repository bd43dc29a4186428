"""Entrance sampling (straylight.engine.entrance_sampling): the source's entrance points drawn from a
density learnt by a pilot trace before the walk. It acts before the first hit, on any kind."""
from __future__ import annotations

from dataclasses import replace

from straylight.engine import entrance_sampling as impl
from straylight.engine.capabilities import Capability
from straylight.engine.strategies.base import ANALOG, BatchContext, Estimator, Strategy, TableTools


class Entrance(Strategy):
    estimator = Estimator("entrance", replace(ANALOG, entrance_sampling=True), Capability.NONE, diffraction=True)
    needs_detector = False  # its own rule below says what it needs
    table_field = "entrance_table"
    table_key = "entrance"
    state_key = "entrance"
    shapes_emission = True

    def rules_out(self, spec, intersector) -> str | None:
        if not impl.applies(spec):
            return "it needs exactly one source and a detector part"
        return None

    def build_table(self, spec, tools: TableTools) -> object:
        return impl.build_table(spec, tools.run_batch, tools.intersector)

    def batch_state(self, ctx: BatchContext) -> object | None:
        return impl.EntranceWeights(ctx.spec, ctx.start_weight_w, ctx.tallies, ctx.rows)


ENTRANCE = Entrance()
