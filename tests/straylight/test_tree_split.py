"""Lobe draws into the split trees (straylight.engine.tree_split, ``EstimatorOptions.tree_split``).

Scene: the slab of tests/straylight/test_reverse_chain.py (10 mm n = 1.5 glass over a r = 4 mm detector
disk) under a glossy plate (z302_sample_b, its narrow lobe's peak sent through the slab onto the
detector) lit by a collimated beam: what reaches the detector is "plate -> slab (T, T or T R R T) ->
detector", the split trees' and the eye chains' family. The analog walk (another seed, every estimator
off) is the independent reference: with K = 8 lobe draws per plate vertex the sum must agree with it
within 4 sigma and keep the ledger exact, alone and with the eye chains (their balance weights per draw).
"""
import math

import numpy as np
import pytest

from engine_helpers import assert_agrees_with_analog, disk_part, quad_part
from geometry.mesh import Scene
from materials import load_material
from straylight.sources import CollimatedDisk
from straylight.trace import EstimatorOptions, TraceOptions, trace

ANALOG = EstimatorOptions(nee=False)


@pytest.fixture(scope="module")
def glossy_slab():
    top = quad_part("top", (-60, -60, 0), (120, 0, 0), (0, 120, 0), "glass", "surface", 6)
    bottom = quad_part("bottom", (-60, -60, -10), (0, 120, 0), (120, 0, 0), "glass", "surface", 6)
    plate = quad_part("plate", (-40, -40, 30), (0, 80, 0), (80, 0, 0), "glossy", "surface", 6)  # normal -z
    det = disk_part("det", -20.0, 4.0, 64, role="detector")
    d = np.array([math.sin(math.radians(35.0)), 0.0, math.cos(math.radians(35.0))])
    src = CollimatedDisk(center_mm=[-49.5, 0.0, 5.0], normal=d, direction=d, radius_mm=6.0)
    mats = {"glass": load_material({"components": [{"type": "dielectric", "n": 1.5}]}, "glass"),
            "glossy": load_material("z302_sample_b")}
    return Scene((top, bottom, plate, det)), src, mats


def _run(scene, n, seed, est):
    sc, src, mats = scene
    return trace(sc, src, n, seed=seed, materials=mats, options=TraceOptions(estimator=est))


@pytest.fixture(scope="module")
def analog(glossy_slab):
    return _run(glossy_slab, 400_000, 4, ANALOG)


@pytest.mark.parametrize("est", [EstimatorOptions(nee=False, delta_chain=4, tree_split=8),
                                 EstimatorOptions(delta_chain=4, reverse_chain=4, tree_split=8)])
def test_lobe_draws_into_the_trees_agree_with_the_analog_walk(glossy_slab, analog, est):
    assert_agrees_with_analog(_run(glossy_slab, 20_000, 5, est), analog)


def test_the_draws_cut_the_variance_and_give_the_same_numbers_for_any_batch_size_and_thread_count(glossy_slab):
    """The draws engage (more error per ray without them) and come from each chunk's own stream: the
    same numbers whatever the batches and threads."""
    from dataclasses import replace

    from straylight.execution import Execution

    sc, src, mats = glossy_slab
    est = EstimatorOptions(nee=False, delta_chain=4, tree_split=8)
    ref = trace(sc, src, 5_432, seed=9, materials=mats, options=TraceOptions(estimator=est, batch_rays=1000))
    got = trace(sc, src, 5_432, seed=9, materials=mats, options=TraceOptions(estimator=est, batch_rays=3000),
                execution=Execution(threads=2))
    assert got.detectors["det"] == ref.detectors["det"]
    plain = trace(sc, src, 5_432, seed=9, materials=mats,
                  options=TraceOptions(estimator=replace(est, tree_split=1), batch_rays=1000)).detectors["det"]
    split = ref.detectors["det"]
    assert split.stderr_w / split.power_w < 0.8 * plain.stderr_w / plain.power_w, (plain, split)


def test_tree_split_must_be_a_positive_integer():
    from straylight.trace import TraceError

    with pytest.raises(TraceError, match="tree_split"):
        EstimatorOptions(tree_split=0)


def test_the_shipped_default_set_agrees_with_the_analog_walk_where_its_lobe_draws_engage(glossy_slab, analog,
                                                                                           monkeypatch):
    """The contract row of the analyses' ``default`` set on a scene where tree_split acts (the contract scenes
    of test_engine_contract.py have no glossy vertex lit by the source ahead of glass): every strategy at
    once, with its lobe draws counted as they engage, agrees with the analog walk within 4 sigma and keeps
    the ledger exact."""
    import straylight.engine.tree_split as tree_split
    from straylight.analyses.estimators import estimator_options

    drawn = []
    original = tree_split.LobeSplit.uniforms

    def counting(self, event, rows):
        drawn.append(len(rows))
        return original(self, event, rows)

    monkeypatch.setattr(tree_split.LobeSplit, "uniforms", counting)
    est = estimator_options("default", materials=glossy_slab[2]).estimator
    assert est.tree_split > 1
    res = _run(glossy_slab, 20_000, 6, est)
    assert sum(drawn) > 0  # the default set's lobe draws engaged
    assert_agrees_with_analog(res, analog)
