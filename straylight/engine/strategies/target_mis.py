"""Target-part MIS (straylight.engine.targets): the scatter directions mix in area sampling of the
scene's target parts (``target_parts``), on top of NEE. Its sampler is part of the compiled scene."""
from __future__ import annotations

from dataclasses import replace

from straylight.engine.capabilities import Capability
from straylight.engine.strategies.base import ANALOG, Estimator, Strategy


class TargetMis(Strategy):
    estimator = Estimator("target_mis", replace(ANALOG, nee=True, target_fraction=0.5), Capability.TARGET_MIS,
                          target=True, requires=("nee",), diffraction=True)


TARGET_MIS = TargetMis()
