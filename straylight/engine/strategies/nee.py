"""Next-event estimation toward the detector parts from the scatter vertices (straylight.engine.nee).
It runs inside the interactions (their vertices call it): no table. Its per-batch state, with
``nee_split`` > ``nee_samples`` (and no edge diffraction), is the split factors of the heavy glossy
vertices (straylight.engine.nee_split), whose walk hits keep the K-sample MIS share."""
from __future__ import annotations

from dataclasses import replace

from straylight.engine.capabilities import Capability
from straylight.engine.nee import SPLIT_KEY
from straylight.engine.nee_split import NeeSplit
from straylight.engine.strategies.base import ANALOG, BatchContext, Estimator, Strategy


class Nee(Strategy):
    estimator = Estimator("nee", replace(ANALOG, nee=True), Capability.NEE, diffraction=True)
    state_key = SPLIT_KEY

    def batch_state(self, ctx: BatchContext) -> object | None:
        est = ctx.spec.options.estimator
        if int(est.nee_split) <= int(est.nee_samples) or ctx.spec.diffraction is not None:
            return None
        if len(ctx.scene.det_parts) == 0 or ctx.scene.target is not None:  # (its lobe draws are the material's)
            return None
        return NeeSplit(ctx)

    def share_walk_hits(self, state, event, rec, rec_w):
        return state.share_walk_hits(event, rec, rec_w)


NEE = Nee()
