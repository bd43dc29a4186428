"""Second-vertex sampling (straylight.engine.second_vertex): the critical surfaces area-sampled as the
second scatter vertex from a table learnt before the walk, MIS with the walk (on top of NEE); and its
lobe variant, whose critical point also leaves along its lobe's own draw (then the walk's hits straight
after such a point keep their share: the per-batch state)."""
from __future__ import annotations

from dataclasses import replace

from straylight.engine import second_vertex as impl
from straylight.engine.capabilities import Capability
from straylight.engine.strategies.base import ANALOG, BatchContext, Estimator, Strategy, TableTools


class SecondVertex(Strategy):
    estimator = Estimator("second_vertex", replace(ANALOG, nee=True, second_vertex_sampling=True),
                          Capability.SECOND_VERTEX, requires=("nee",))
    table_field = "critical_table"
    table_key = "second"
    table_ships_early = True

    def rules_out(self, spec, intersector) -> str | None:
        return impl.unsupported(spec)

    def build_table(self, spec, tools: TableTools) -> object:
        return impl.build_table(spec, tools.runtime.scene(spec, tools.intersector))

    def batch_state(self, ctx: BatchContext) -> object | None:
        return ctx.spec.critical_table  # the table is all it keeps

    def nee_weights(self, state, event, verts, w_vertex):
        """The vertices reached straight from a scatter vertex keep their walk share of NEE."""
        return impl.walk_weights(event, verts, w_vertex)

    def after_nee(self, state, event, verts, frame) -> None:
        """Each vertex draws its critical second vertex, and NEE from there."""
        impl.estimate(event, verts, frame)


class SecondVertexLobe(Strategy):
    """Second-vertex sampling whose critical point also leaves along its lobe's own draw (the table is
    second_vertex's)."""

    estimator = Estimator("second_vertex_lobe",
                          replace(ANALOG, nee=True, second_vertex_sampling=True, second_vertex_lobe_sampling=True),
                          Capability.SECOND_VERTEX, requires=("nee",))
    state_key = "second_vertex"
    table_from = "critical_table"

    def rules_out(self, spec, intersector) -> str | None:
        return impl.unsupported(spec)

    def batch_state(self, ctx: BatchContext) -> object | None:
        return impl.SecondVertexShares(ctx.n_rays)

    def share_walk_hits(self, state, event, rec, rec_w):
        return state.share_after_vertex(event, rec, rec_w)


SECOND_VERTEX = SecondVertex()
SECOND_VERTEX_LOBE = SecondVertexLobe()
