"""Reflections into a detector counted by their expected value (EstimatorOptions.reflection_split,
straylight.engine.reflection_split).

Scene: a beam lights a grey Lambertian floor; a flat glass plate (n = 2, uncoated: ~11 % reflected
near normal incidence) hangs above it; a small front-only detector beside the beam faces the plate,
so the only light it counts is floor scatter reflected by the plate (its back sees the floor: next-event
estimation from the floor gives nothing). The walk reaches the detector only through the plate's
reflection branch (picked with probability ~R); the split counts R for every floor ray that meets the
plate where the reflection lands on the detector. Checked against the analog walk (no NEE, no
splitting) within 4 combined standard errors, with the ledger exact, and with a smaller error at
equal rays. (The contract test runs it on every interaction kind: row ``reflection_split``.)"""
import math

import numpy as np
import pytest

from engine_helpers import StandInLambertian, disk_part
from geometry.mesh import Part, Scene
from straylight.sources import CollimatedDisk
from straylight.trace import EstimatorOptions, OutputOptions, TraceOptions, trace

ANALOG = TraceOptions(estimator=EstimatorOptions(nee=False))
SPLIT = TraceOptions(estimator=EstimatorOptions(nee=False, reflection_split=True), output=OutputOptions(detector_sides="front"))


@pytest.fixture(scope="module")
def scene():
    from materials import load_material

    floor = disk_part("floor", 0.0, 60.0, 64, role="surface", material="grey")
    v = np.array([[-40.0, -40.0, 50.0], [40.0, -40.0, 50.0], [40.0, 40.0, 50.0], [-40.0, 40.0, 50.0]])
    # normal -z: the plate's front (air side) faces the floor, its glass (the back) above
    plate = Part("plate", v, np.array([[0, 2, 1], [0, 3, 2]]), material="glass", role="surface")
    det = disk_part("det", 0.0, 8.0, 64, role="detector")
    det = Part("det", det.vertices_mm + np.array([35.0, 0.0, 25.0]), det.faces, role="detector")  # faces +z
    mats = {"grey": StandInLambertian(0.5),
            "glass": load_material({"components": [{"type": "dielectric", "n": 2.0}]}, "glass")}
    d = np.array([0.0, 0.0, -1.0])
    return Scene((floor, plate, det)), CollimatedDisk(center_mm=[0.0, 0.0, 100.0], normal=d, direction=d,
                                                      radius_mm=15.0), mats


def test_reflection_split_agrees_with_the_analog_walk_and_cuts_the_error(scene):
    from dataclasses import replace

    sc, src, mats = scene
    analog = trace(sc, src, 400_000, seed=51, materials=mats, options=replace(ANALOG, output=OutputOptions(detector_sides="front")))
    walk = trace(sc, src, 40_000, seed=52, materials=mats, options=replace(SPLIT, estimator=replace(SPLIT.estimator, reflection_split=False)))
    split = trace(sc, src, 40_000, seed=52, materials=mats, options=SPLIT)
    a, w, s = analog.detectors["det"], walk.detectors["det"], split.detectors["det"]
    assert a.power_w > 0 and s.power_w > 0 and w.power_w > 0  # light reaches the detector only via the plate
    assert abs(a.power_w - s.power_w) <= 4 * math.hypot(a.stderr_w, s.stderr_w), (a, s)
    assert abs(split.ledger["balance_residual_w"]) < 1e-9
    assert s.stderr_w / s.power_w < 0.5 * w.stderr_w / w.power_w, (w, s)
