"""Scatter points lit through a lens (straylight.engine.lens_vertex): the first scatter vertices behind a run
of refracting surfaces, area-sampled from a table learnt before the walk and joined to the collimated beam by
solving the run for the entrance point, MIS with the walk. Off where its probes see no such vertex that a
detector sees."""
from __future__ import annotations

from dataclasses import replace

from straylight.engine import lens_vertex as impl
from straylight.engine.capabilities import Capability
from straylight.engine.strategies.base import ANALOG, BatchContext, Estimator, Strategy, TableTools


class LensVertex(Strategy):
    # it draws on the parts first-vertex sampling may (Capability.FIRST_VERTEX), but only behind a run of analytic
    # refracting surfaces, which no kind's contract scene has: declared on no kind's parts, it must not engage there
    estimator = Estimator("lens_vertex", replace(ANALOG, lens_vertex=True), Capability.NONE, reference=False)
    table_field = "lens_table"
    table_key = "lens"
    state_key = "lens_vertex"

    def rules_out(self, spec, intersector) -> str | None:
        if intersector is not None:
            return "its table is built on embree, and this trace has its own intersector"
        return impl.unsupported(spec)

    def build_table(self, spec, tools: TableTools) -> object:
        return impl.build_table(spec, tools.runtime.scene(spec, tools.intersector))

    def declines(self, spec) -> str | None:
        table = spec.lens_table
        if table is not None and table.empty:
            return "its probes saw no scatter point lit through a lens that a detector sees straight"
        return None

    def batch_state(self, ctx: BatchContext) -> object | None:
        return impl.LensVertexWeights(ctx.spec, ctx.spec.lens_table, ctx.n_rays)

    def vertex_weights(self, state, event, verts, w_vertex):
        return state.vertex_weights(event, verts, w_vertex)

    def share_walk_hits(self, state, event, rec, rec_w):
        return state.share_walk_hits(event, rec, rec_w)

    def after_walk(self, state, ctx: BatchContext) -> int:
        opt = ctx.spec.options.output
        return impl.run_pass(ctx.spec, ctx.scene, ctx.spec.lens_table, ctx.first_chunk, ctx.stop_chunk, ctx.tallies,
                             ctx.rows, ctx.records, bool(opt.record_paths), int(opt.path_depth))


LENS_VERTEX = LensVertex()
