"""Target-part MIS (straylight.engine.targets): the scatter directions mix in area sampling of the
scene's target parts (``target_parts``), on top of NEE. Its sampler is part of the compiled scene; the
scatter kinds draw from the mixture, and NEE weighs its samples against the mixture's density (its hook)."""
from __future__ import annotations

from dataclasses import replace

from straylight.engine import targets as impl
from straylight.engine.capabilities import Capability
from straylight.engine.strategies.base import ANALOG, BatchContext, Estimator, Strategy


class TargetMis(Strategy):
    estimator = Estimator("target_mis", replace(ANALOG, nee=True, target_fraction=0.5), Capability.TARGET_MIS,
                          target=True, requires=("nee",), diffraction=True)

    def batch_state(self, ctx: BatchContext) -> object | None:
        return impl.TargetMixture(ctx.scene.target, ctx.spec.options.estimator.target_fraction, ctx.spec.eps)

    def nee_density(self, state, event, verts):
        return state.density(event, verts)


TARGET_MIS = TargetMis()
