"""The strategy plan (straylight.engine.plan): which requested strategies run on a trace, decided once,
and why the others do not (a diffracting part, no detector, polarized light, several sources), returned
with the result and written by ``straylight trace --json`` instead of being dropped silently."""
from __future__ import annotations

import json
from dataclasses import replace

import pytest

from straylight.cli.main import main
from straylight.engine.estimators import ANALOG, ESTIMATORS, options_for
from straylight.engine.plan import requested
from straylight.scene import load_scene
from straylight.trace import EstimatorOptions, PhysicsOptions, TraceOptions

from tests.straylight.test_diffraction_scene import write_scene

pytestmark = pytest.mark.filterwarnings("ignore::UserWarning")  # open analytic planes are not watertight

VERTEX = EstimatorOptions(nee=True, first_vertex_sampling=True, second_vertex_sampling=True)


def test_each_row_requests_itself_and_the_analog_walk_requests_none():
    for est in ESTIMATORS:
        assert requested(est, options_for(est, "detector")), est.name
        assert not requested(est, ANALOG), est.name


def test_a_diffracting_part_turns_the_edge_blind_strategies_off_and_says_why(tmp_path):
    rs = load_scene(write_scene(tmp_path))
    res = rs.trace(2000, seed=1, options=TraceOptions(estimator=VERTEX))
    plan = res.strategies
    assert "nee" in plan.on
    off = dict(plan.off)
    assert "first_vertex" in off and "diffract" in off["first_vertex"]
    # the same numbers as a trace that never asked for them (the plan reports; it does not change the walk)
    plain = rs.trace(2000, seed=1, options=TraceOptions(estimator=EstimatorOptions(nee=True)))
    assert res.detectors["screen"].power_w == plain.detectors["screen"].power_w
    # without diffraction diffraction turns none off: first-vertex sampling is asked for and possible; here it
    # declines for its own reason (the beam lights the stop's top, the screen sees only its underside)
    geo = rs.trace(2000, seed=1, options=TraceOptions(estimator=VERTEX, physics=PhysicsOptions(diffraction="off")))
    assert "nee" in geo.strategies.on and not any("diffract" in why for why in dict(geo.strategies.off).values())
    assert dict(geo.strategies.off)["first_vertex"].startswith("its probes saw no surface")


def test_no_detector_says_so(tmp_path):
    scene = write_scene(tmp_path, diffraction="")
    scene.write_text(scene.read_text().replace('role = "detector"', 'material = "black"'))
    res = load_scene(scene).trace(1000, seed=1, options=TraceOptions(estimator=EstimatorOptions(nee=True)))
    assert dict(res.strategies.off) == {"nee": "the scene has no detector part"}


def test_trace_json_names_the_strategies(tmp_path):
    scene = write_scene(tmp_path)
    out = tmp_path / "t.json"
    assert main(["trace", str(scene), "--rays", "2000", "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert "nee" in doc["strategies"]["on"]
    assert "diffract" in doc["strategies"]["off"]["first_vertex"]


def test_a_strategy_asked_for_and_possible_runs(tmp_path):
    # the beam from below: it lights the stop's underside, which the screen sees (first-vertex sampling has
    # surfaces to draw)
    scene = write_scene(tmp_path, diffraction="")
    scene.write_text(scene.read_text().replace("center_mm = [0.0, 0.0, 5.0]", "center_mm = [0.0, 0.0, -5.0]")
                     .replace("normal = [0.0, 0.0, -1.0]\ndirection = [0.0, 0.0, -1.0]",
                              "normal = [0.0, 0.0, 1.0]\ndirection = [0.0, 0.0, 1.0]"))
    rs = load_scene(scene)
    on = rs.trace(2000, seed=3, options=TraceOptions(estimator=replace(ANALOG, first_vertex_sampling=True)))
    assert on.strategies.on == ("first_vertex",) and on.strategies.off == ()
    analog = rs.trace(2000, seed=3, options=TraceOptions(estimator=ANALOG))
    assert analog.strategies.on == () and analog.strategies.off == ()


def test_a_spec_without_its_table_runs_without_the_strategy(tmp_path):
    """A spec straight from make_spec (no trace(): no tables built) asks for first-vertex sampling: the
    walk's plan (straylight.engine.plan.running) leaves it out, saying so; with the plan set on the spec
    the walk takes that as it is."""
    from dataclasses import replace

    from straylight.engine.plan import resolve, running, without_missing_tables
    from straylight.trace import make_spec

    rs = load_scene(write_scene(tmp_path, diffraction=""))
    options = TraceOptions(estimator=replace(ANALOG, nee=True, first_vertex_sampling=True))
    spec = make_spec(rs.scene, rs.sources, 1000, 1, rs.materials, options)
    assert resolve(options, spec).on == ("nee", "first_vertex")
    assert running(spec) == ("nee",)
    plan = without_missing_tables(resolve(options, spec), spec, "not built")
    assert dict(plan.off) == {"first_vertex": "not built"}
    assert running(replace(spec, strategies_on=("first_vertex",))) == ("first_vertex",)
