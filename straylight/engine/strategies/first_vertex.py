"""First-vertex sampling (straylight.engine.first_vertex): the single-scatter vertices area-sampled from a
table learnt before the walk, MIS with the walk; and its lobe variant, which also joins the vertex to the
detector by the lobe's own draw (the same table and state: the switch is read by the implementation)."""
from __future__ import annotations

from dataclasses import replace

from straylight.engine import first_vertex as impl
from straylight.engine.capabilities import Capability
from straylight.engine.strategies.base import ANALOG, BatchContext, Estimator, Strategy, TableTools


def _own_intersector(spec, intersector) -> str | None:
    if intersector is not None:
        return "its table is built on embree, and this trace has its own intersector"
    return None


def _nothing_to_draw(spec) -> str | None:
    """Why a built table leaves the strategy nothing to do: no surface triangle to draw (its MIS weights
    would all be the walk's, 1: turning it off changes no number)."""
    table = spec.vertex_table
    if table is not None and len(table.tri) == 0:
        return "its probes saw no surface the source lights and a detector sees straight"
    return None


class FirstVertex(Strategy):
    estimator = Estimator("first_vertex", replace(ANALOG, first_vertex_sampling=True), Capability.FIRST_VERTEX,
                          reference=False)
    table_field = "vertex_table"
    table_key = "first"
    table_ships_early = True
    state_key = "first_vertex"

    def rules_out(self, spec, intersector) -> str | None:
        return _own_intersector(spec, intersector)

    def build_table(self, spec, tools: TableTools) -> object:
        return impl.build_table(spec, tools.runtime.scene(spec, tools.intersector))  # None: embree (rules_out)

    def declines(self, spec) -> str | None:
        return _nothing_to_draw(spec)

    def batch_state(self, ctx: BatchContext) -> object | None:
        return impl.FirstVertexWeights(ctx.spec, ctx.spec.vertex_table, ctx.n_rays)

    def vertex_weights(self, state, event, verts, w_vertex):
        return state.vertex_weights(event, verts)  # the first of its kind: w_vertex is None

    def share_walk_hits(self, state, event, rec, rec_w):
        return state.share_single_scatter(event, rec, rec_w)

    def after_walk(self, state, ctx: BatchContext) -> int:
        opt = ctx.spec.options.output
        return impl.run_vertex_pass(ctx.spec, ctx.scene, ctx.spec.vertex_table, ctx.first_chunk, ctx.stop_chunk,
                                    ctx.tallies, ctx.rows, ctx.records, bool(opt.record_paths), int(opt.path_depth))


class FirstVertexLobe(Strategy):
    """First-vertex sampling joined to the detector by the lobe's own draw as well (its table and state are
    first_vertex's)."""

    estimator = Estimator("first_vertex_lobe", replace(ANALOG, first_vertex_sampling=True, vertex_lobe_sampling=True),
                          Capability.FIRST_VERTEX, reference=False)
    table_from = "vertex_table"

    def rules_out(self, spec, intersector) -> str | None:
        return _own_intersector(spec, intersector)

    def declines(self, spec) -> str | None:
        return _nothing_to_draw(spec)


FIRST_VERTEX = FirstVertex()
FIRST_VERTEX_LOBE = FirstVertexLobe()
