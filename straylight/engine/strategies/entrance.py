"""Entrance sampling (straylight.engine.entrance_sampling): the source's entrance points drawn from a
density learnt by a pilot trace before the walk. It acts before the first hit, on any kind. Its pilot's
estimate of the detected power is left in ``TableTools.measured["detected_w"]`` for the tables after it
(the eye pilot weighs its chains' share of the light by it: straylight.engine.reverse_chain)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from straylight.engine import entrance_sampling as impl
from straylight.engine.capabilities import Capability
from straylight.engine.strategies.base import ANALOG, BatchContext, Estimator, Strategy, TableTools
from straylight.rng import CHUNK_RAYS


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
        table = impl.build_table(spec, counted, tools.intersector)
        if tools.measured is not None and counted.detected_w is not None:
            tools.measured["detected_w"] = counted.detected_w
        return table

    def batch_state(self, ctx: BatchContext) -> object | None:
        return impl.EntranceWeights(ctx.spec, ctx.start_weight_w, ctx.tallies, ctx.rows)


ENTRANCE = Entrance()
