"""Entrance sampling (straylight.engine.entrance_sampling): the source's entrance points drawn from a
density learnt by a pilot trace before the walk. It acts before the first hit, on any kind. Its pilot's
estimate of the detected power is left in ``TableTools.measured["detected_w"]`` for the tables after it
(the eye pilot weighs its chains' share of the light by it: straylight.engine.reverse_chain). Where the run
traces eye chains, the eye pilot runs after the pilot's first stage (with that stage's detected power) and the rest
of the pilot runs the chains with its table; the eye table is left in ``measured[EYE_TABLE]`` for the reverse
chains' own build_table. For one collimated
beam into a lens, a share of the table is drawn from the entrance points that light the scatter points behind the
glass a detector sees (straylight.engine.lens_vertex's table, solved for their entrance points)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from straylight.engine import entrance_sampling as impl
from straylight.engine import lens_vertex, reverse_chain
from straylight.engine.capabilities import Capability
from straylight.engine.strategies.base import ANALOG, BatchContext, Estimator, Strategy, TableTools
from straylight.engine.strategies.lens_vertex import LENS_VERTEX
from straylight.engine.strategies.reverse_chain import EYE_TABLE, REVERSE_CHAIN
from straylight.rng import CHUNK_RAYS, check_seed


class PilotPower:
    """``run_batch`` that also sums what the pilot's batches put on the detectors (their path records):
    :attr:`detected_w` is the pilot's estimate of the detected power, W (each batch's sum brought to its
    spec's n_rays, the start weight's 1 / N, and pooled by rays traced; None before any ray)."""

    def __init__(self, run_batch):
        self.run_batch = run_batch
        self.scaled_w = 0.0  # sum over batches of (their records' power x n_rays of their spec)
        self.rays = 0

    def __call__(self, spec, first_chunk, stop_chunk, *args, **kw):
        res = self.run_batch(spec, first_chunk, stop_chunk, *args, **kw)
        traced = min(stop_chunk * CHUNK_RAYS, int(spec.n_rays)) - first_chunk * CHUNK_RAYS
        paths = res.get("paths")
        if traced > 0 and paths is not None:
            self.scaled_w += float(np.sum(np.asarray(paths["power_w"], dtype=np.float64))) * int(spec.n_rays)
            self.rays += traced
        return res

    @property
    def detected_w(self) -> float | None:
        return self.scaled_w / self.rays if self.rays else None


#: share of the entrance table drawn from the entrance points that light lens_vertex's scatter points (the glints
#: of a lens's cell or mount behind the glass; straylight.engine.lens_vertex.glint_entrances): on the guide scope at
#: 15 deg a crescent of the beam lights both the cell's bore and, by the back face's reflection, its lip, and the
#: pilot's table gave it little mass (docs/engine.md, "Entrance points of the glints")
LENS_COMPONENT = 0.1
#: scatter points drawn from the lens table and solved for their entrance points
LENS_COMPONENT_POINTS = 8192
LENS_COMPONENT_STREAM = 0x454E5443  # the second entropy word of their draws ("ENTC")


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
        counted = PilotPower(tools.run_batch)
        eyes = None
        if tools.measured is not None and tools.plan is not None and tools.plan.runs(REVERSE_CHAIN.name):
            def eyes():
                # the eye pilot weighs its chains against what the first stage detected; its table is the run's
                # (left in measured for the reverse chains' own build_table), and the rest of this pilot runs the
                # chains with it (entrance_sampling.build_table)
                tools.measured["detected_w"] = counted.detected_w
                eye_table = tools.measured[EYE_TABLE] = REVERSE_CHAIN.build_table(spec, tools)
                return eye_table if isinstance(eye_table, reverse_chain.EyeTable) else None
        table = impl.build_table(spec, counted, tools.intersector, eye_table=eyes,
                                 chain_family=lambda events: reverse_chain.chain_family(spec, events))
        if tools.measured is not None and counted.detected_w is not None and EYE_TABLE not in tools.measured:
            tools.measured["detected_w"] = counted.detected_w
        if table is None or tools.intersector is not None or lens_vertex.unsupported(spec) is not None:
            return table  # (the lens table is built on embree, for one collimated beam)
        lens = tools.runtime.table(LENS_VERTEX.table_key, spec, lambda: LENS_VERTEX.build_table(spec, tools))
        glints = lens_vertex.glint_entrances(spec, lens, LENS_COMPONENT_POINTS, (check_seed(spec.seed), LENS_COMPONENT_STREAM))
        return impl.with_component(table, glints, LENS_COMPONENT)

    def batch_state(self, ctx: BatchContext) -> object | None:
        return impl.EntranceWeights(ctx.spec, ctx.start_weight_w, ctx.tallies, ctx.rows)


ENTRANCE = Entrance()
