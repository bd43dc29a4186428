"""Specular next-event estimation (straylight.engine.specular_nee): from the walk's plain scatter
vertices to the detectors through one to four analytic interfaces (Newton's method; a singlet's ghosts by
shooting), combined with the split trees (and, for the ghosts, the eye chains) by the balance heuristic."""
from __future__ import annotations

from dataclasses import replace

from straylight.engine import specular_nee as impl
from straylight.engine.capabilities import Capability
from straylight.engine.strategies.base import ANALOG, BatchContext, Estimator, Strategy


class SpecularNeeStrategy(Strategy):
    # Capability.NONE: its vertices are plain scatter vertices and the interfaces it crosses need an
    # analytic surface, which no mesh part of a kind has (the contract scenes); it crosses only parts
    # whose kind declares DELTA_CHAIN (impl.interface_parts). Its own checks: test_specular_nee.py.
    estimator = Estimator("specular_nee", replace(ANALOG, delta_chain=4, specular_nee=2), Capability.NONE,
                          reference=False, requires=("delta_chain",))
    state_key = "specular_nee"

    def rules_out(self, spec, intersector) -> str | None:
        return impl.unsupported(spec)

    def uniform_columns(self, spec) -> int:
        return 3 * len(spec.detector_parts)  # a detector point per detector and vertex

    def batch_state(self, ctx: BatchContext) -> object | None:
        return impl.SpecularNee(ctx, ctx.capabilities.parts(Capability.DELTA_CHAIN))

    def after_hits(self, state, event, continuing) -> None:
        state.after_hits(event, continuing, event.columns.of(self.name))

    def after_interactions(self, state, event, continuing, outgoing) -> None:
        state.after_interactions(event, continuing, outgoing)

    def after_walk(self, state, ctx: BatchContext) -> int:
        return state.shadow_rays


SPECULAR_NEE = SpecularNeeStrategy()
