"""Lobe draws at the split trees' branch ends (straylight.engine.tree_ends, ``EstimatorOptions.tree_ends``).

Scene: a 10 mm n = 1.5 glass slab, a collimated beam onto its top face at 35 deg, a glossy plate (z302_sample_b)
above it facing down where the top face's reflection lands, and a detector disk below the slab where the
plate's lobe peak comes down through it (the specular ray: plate at x = 21 mm, slab top at 42, bottom at 46.1,
z = -20 at 53.1), and a second detector above the slab where the plate's lobe comes back up off the top face.
What reaches the lower one is "top (R) -> plate -> slab (T, T) -> detector" and "top (T) ->
bottom (R) -> top (T) -> plate -> slab -> detector": the plate is lit only by reflections, which the walk takes
~4 % of the time; the trees follow both branches by expected weight and stop at the plate, where the end draws
go on. The analog walk (another seed, every estimator off) is the independent reference.
"""
import math
from dataclasses import replace

import numpy as np
import pytest

from engine_helpers import assert_agrees_with_analog, disk_part, quad_part
from geometry.mesh import Part, Scene
from materials import load_material
from straylight.sources import CollimatedDisk
from straylight.trace import EstimatorOptions, TraceError, TraceOptions, trace

ANALOG = EstimatorOptions(nee=False)
TREES = EstimatorOptions(nee=False, delta_chain=4, tree_split=2)


def _scene(n_glass):
    top = quad_part("top", (-60, -60, 0), (120, 0, 0), (0, 120, 0), "glass", "surface", 6)
    bottom = quad_part("bottom", (-60, -60, -10), (0, 120, 0), (120, 0, 0), "glass", "surface", 6)
    plate = quad_part("plate", (0, -40, 30), (0, 80, 0), (80, 0, 0), "glossy", "surface", 6)  # normal -z
    disk = disk_part("det", -20.0, 15.0, 64, role="detector")
    det = Part("det", disk.vertices_mm + np.array([53.0, 0.0, 0.0]), disk.faces, role="detector")
    # above the slab, facing down, where the plate's lobe comes back up off the top face ("plate -> top (R) -> up")
    upper = disk_part("up", 15.0, 6.0, 64, role="detector", facing=-1)
    up = Part("up", upper.vertices_mm + np.array([52.5, 0.0, 0.0]), upper.faces, role="detector")
    th = math.radians(35.0)
    d = np.array([math.sin(th), 0.0, -math.cos(th)])
    src = CollimatedDisk(center_mm=(-24.4 * d).tolist(), normal=d, direction=d, radius_mm=6.0)
    mats = {"glass": load_material({"components": [{"type": "dielectric", "n": n_glass}]}, "glass"),
            "glossy": load_material("z302_sample_b")}
    return Scene((top, bottom, plate, det, up)), src, mats


@pytest.fixture(scope="module")
def reflected_glint():
    return _scene(1.5)


def _run(scene, n, seed, est, **kw):
    sc, src, mats = scene
    return trace(sc, src, n, seed=seed, materials=mats, options=TraceOptions(estimator=est, **kw))


@pytest.fixture(scope="module")
def analog(reflected_glint):
    return _run(reflected_glint, 400_000, 4, ANALOG)


@pytest.mark.parametrize("est", [replace(TREES, tree_ends=True),
                                 EstimatorOptions(delta_chain=4, reverse_chain=4, tree_split=4, tree_ends=True,
                                                  entrance_sampling=True)])
def test_end_draws_agree_with_the_analog_walk(reflected_glint, analog, est):
    assert_agrees_with_analog(_run(reflected_glint, 20_000, 5, est), analog)


def test_after_an_end_the_walk_keeps_the_runs_with_a_reflection(reflected_glint, analog):
    """The end draws' trees follow transmissions only: "plate -> top (R) -> up" (the detector above the slab) is
    the walk's own tree's after the plate, at its full weight."""
    assert_agrees_with_analog(_run(reflected_glint, 20_000, 5, replace(TREES, tree_ends=True)), analog, "up")


def test_ends_weaker_than_the_draw_threshold_are_drawn_by_roulette_and_stay_unbiased():
    """n = 1.2: the top face reflects ~1 % at 35 deg, so an end is drawn with probability w_P / (0.02 w_root) ~ 0.4
    and weighs 1 / q (tree_ends.END_TAU); against the analog walk of the same scene."""
    import straylight.engine.tree_ends as tree_ends

    scene = _scene(1.2)
    q = []
    original = tree_ends.TreeEnds._draws

    def recording(self, event, e, p, nf, part):
        w_root = event.rays.weight_w[e.row]
        q.extend(np.minimum(1.0, e.w / (tree_ends.END_TAU * w_root)))
        return original(self, event, e, p, nf, part)

    analog = _run(scene, 400_000, 4, ANALOG)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(tree_ends.TreeEnds, "_draws", recording)
        res = _run(scene, 20_000, 5, replace(TREES, tree_ends=True))
    assert 0.2 < np.median(q) < 0.8, np.median(q)  # the roulette engaged on the single reflections
    assert_agrees_with_analog(res, analog)


def test_end_draws_cut_the_variance_of_light_that_reached_a_glossy_part_by_reflection(reflected_glint):
    """Without them the walk reaches the plate by its ~4 % reflection choice (2.5 % at 2e4 rays); with them every
    ray whose reflection lights the plate does (measured 0.18 %)."""
    plain = _run(reflected_glint, 20_000, 5, TREES).detectors["det"]
    ends = _run(reflected_glint, 20_000, 5, replace(TREES, tree_ends=True)).detectors["det"]
    assert ends.stderr_w / ends.power_w < 0.25 * plain.stderr_w / plain.power_w, (plain, ends)


def test_the_same_numbers_for_any_batch_size_and_thread_count(reflected_glint):
    from straylight.execution import Execution

    est = replace(TREES, tree_ends=True)
    ref = _run(reflected_glint, 5_432, 9, est, batch_rays=1000)
    got = trace(reflected_glint[0], reflected_glint[1], 5_432, seed=9, materials=reflected_glint[2],
                options=TraceOptions(estimator=est, batch_rays=3000), execution=Execution(threads=2))
    assert got.detectors["det"] == ref.detectors["det"]


def test_the_records_carry_the_root_run_the_end_and_the_draw_run(reflected_glint):
    """Path records of an end draw's branch: top (R) -> plate -> top (T) -> bottom (T) -> det, its power that
    family's."""
    from straylight.analyses.paths_report import path_report
    from straylight.trace import OutputOptions

    res = _run(reflected_glint, 4_000, 3, replace(TREES, tree_ends=True),
               output=OutputOptions(record_paths=True, path_depth=8))
    tally = res.detectors["det"]
    rep = path_report(res.paths, "det", tally, group_by="family")
    labels = {r.label: r.fraction for r in rep.rows}
    family = "source -> top (specular) -> plate -> top (specular) -> bottom (specular) -> det"
    assert labels.get(family, 0.0) > 0.3, labels
    assert abs(sum(r.fraction for r in rep.rows) - 1.0) < 1e-9


def test_tree_ends_must_be_a_switch():
    with pytest.raises(TraceError, match="tree_ends"):
        EstimatorOptions(tree_ends=2)


def test_no_end_draws_where_the_walk_fixes_the_polarization(reflected_glint, monkeypatch):
    """Under ``polarization = "s"`` every vertex is evaluated for s light, not the trees' Stokes vectors: the end
    draws stay off (tree_ends.unsupported), and the trace runs with the trees alone."""
    import straylight.engine.tree_ends as tree_ends
    from straylight.trace import PhysicsOptions

    drawn = []
    monkeypatch.setattr(tree_ends.TreeEnds, "draw", lambda self, event, chains: drawn.append(1))
    res = _run(reflected_glint, 2_000, 5, replace(TREES, tree_ends=True), physics=PhysicsOptions(polarization="s"))
    assert res.detectors["det"].power_w > 0
    assert not drawn
    res = _run(reflected_glint, 2_000, 5, replace(TREES, tree_ends=True))
    assert drawn  # (the same scene draws them with unpolarized light)


def test_the_shipped_default_set_agrees_with_the_analog_walk_where_its_end_draws_engage(reflected_glint, analog,
                                                                                          monkeypatch):
    """The contract row of the analyses' ``default`` set on a scene where the end draws act (the contract scenes of
    test_engine_contract.py have no glossy part lit through glass): every strategy at once, the end draws counted
    as they engage, against the analog walk within 4 sigma with the ledger exact."""
    import straylight.engine.tree_ends as tree_ends
    from straylight.analyses.estimators import estimator_options

    drawn = []
    original = tree_ends.TreeEnds._draws

    def counting(self, event, e, p, nf, part):
        drawn.append(len(e.w))
        return original(self, event, e, p, nf, part)

    monkeypatch.setattr(tree_ends.TreeEnds, "_draws", counting)
    est = estimator_options("default", materials=reflected_glint[2]).estimator
    assert est.tree_ends
    res = _run(reflected_glint, 20_000, 6, est)
    assert sum(drawn) > 0
    assert_agrees_with_analog(res, analog)
