"""Next-event estimation toward the detector parts from the scatter vertices (straylight.engine.nee).
It runs inside the interactions (their vertices call it): no table, no per-batch state."""
from __future__ import annotations

from dataclasses import replace

from straylight.engine.capabilities import Capability
from straylight.engine.strategies.base import ANALOG, Estimator, Strategy


class Nee(Strategy):
    estimator = Estimator("nee", replace(ANALOG, nee=True), Capability.NEE, diffraction=True)


NEE = Nee()
