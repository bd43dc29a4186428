"""bluesky plans, checked by the messages they emit (bluesky: src/bluesky/tests/test_new_examples.py)
and by one run on the simulated rig for the documents."""
import json

import pytest

from materials.lambertian import Lambertian
from rig.devices import sim_devices
from rig.plans import (HWP_DEG, PlanError, Point, arm_deg, brdf_scan, load_plan, paper_points,
                       paper_theta_r_deg, plan_spec_from_dict, point_key)
from rig.sim import SimRig


@pytest.fixture
def rig():
    sim = SimRig(Lambertian(0.1), seed=0, ideal=True)
    return sim, sim_devices(sim)


def summary(msgs):
    return [(m.command, getattr(m.obj, "name", None), tuple(m.args)) for m in msgs]


def test_brdf_scan_messages(rig):
    _, d = rig
    points = [Point(30.0, "s", 30.0, 0.0), Point(30.0, "p", 20.0, 180.0)]
    msgs = list(brdf_scan(d, points, n_readings=3, md={"sample": "x"}))
    got = summary(msgs)
    staged = ["lockin", "laser", "chopper", "point", "sample_stage", "arm", "hwp"]
    def point_msgs(p, arm):
        return ([("checkpoint", None, ()), ("set", "point", (tuple(p),)), ("set", "sample_stage", (p.theta_i_deg,)),
                 ("set", "arm", (arm,)), ("wait", None, ()), ("create", None, ())]
                + [("trigger", n, ()) for n in ("lockin", "laser", "chopper")] + [("wait", None, ())]
                + [("read", n, ()) for n in staged] + [("save", None, ())])

    expected = ([("stage", n, ()) for n in staged] + [("open_run", None, ())]
                + [("set", "lockin_n_readings", (3,)), ("wait", None, ())]
                + [("set", "hwp", (0.0,)), ("wait", None, ())] + point_msgs(points[0], 60.0)
                + [("set", "hwp", (45.0,)), ("wait", None, ())] + point_msgs(points[1], 10.0)
                + [("close_run", None, ())] + [("unstage", n, ()) for n in reversed(staged)])
    assert got == expected
    open_run = next(m for m in msgs if m.command == "open_run")
    assert open_run.kwargs["sample"] == "x" and open_run.kwargs["n_points_total"] == 2
    # each point reads every device: lock-in, laser, chopper, point, three axes
    fields = set()
    for dev in d.all():
        fields |= set(dev.read())
    assert fields == {
        "lockin_mean_v", "lockin_std_v", "lockin_n", "lockin_discarded", "laser_power_w", "chopper_frequency_hz",
        "point_theta_i_deg", "point_theta_r_deg", "point_phi_r_deg", "point_polarization",
        "sample_stage", "sample_stage_setpoint", "arm", "arm_setpoint", "hwp", "hwp_setpoint"}


def test_skip_leaves_out_completed_points(rig):
    _, d = rig
    points = [Point(30.0, "s", tr, 0.0) for tr in (29.95, 30.0, 30.05)]
    msgs = list(brdf_scan(d, points, skip={point_key(30.0, "s", 30.0, 0.0)}))
    measured = [m.args[0] for m in msgs if m.command == "set" and m.obj.name == "point"]
    assert measured == [tuple(points[0]), tuple(points[2])]


def test_arm_geometry():
    assert arm_deg(Point(30.0, "s", 45.0, 0.0)) == 75.0   # specular side: theta_i + theta_r
    assert arm_deg(Point(30.0, "s", 20.0, 180.0)) == 10.0  # backscatter side: theta_i - theta_r
    assert HWP_DEG == {"s": 0.0, "p": 45.0}


def test_paper_grid_zones():
    # Zones written out by hand from the module table (0.05 / 0.2 / 0.5 / 5 deg steps).
    core = [round(0.05 * k, 2) for k in range(-10, 11)]
    shoulder = [round(0.5 + 0.2 * k, 1) for k in range(1, 11)]
    near = [3.0, 3.5, 4.0, 4.5, 5.0]
    wing = [10.0 + 5 * k for k in range(17)]
    offsets = sorted(set(core + shoulder + [-x for x in shoulder] + near + [-x for x in near] + wing + [-x for x in wing]))
    for ti in (10.0, 30.0, 40.0, 70.0, 80.0):
        expected = [round(ti + d, 6) for d in offsets if 0.0 <= ti + d <= 85.0]
        assert paper_theta_r_deg(ti).tolist() == pytest.approx(expected, abs=1e-9)
    pts = paper_points()
    assert {p.theta_i_deg for p in pts} == {10.0, 30.0, 40.0, 70.0, 80.0}
    assert [p.polarization for p in pts[:1]] == ["s"] and pts[-1].polarization == "p"
    assert len(pts) == len({point_key(*p) for p in pts})  # no duplicates
    assert len(paper_theta_r_deg(40.0)) == 21 + 20 + 10 + 15  # core, shoulder, near, wings 0..35 and 50..85


def test_custom_plan_file(tmp_path):
    path = tmp_path / "plan.json"
    path.write_text(json.dumps({
        "name": "mine", "n_readings": 5, "polarizations": ["p"],
        "incidence": [{"theta_i_deg": 20, "theta_r_deg": [0, 19.5, 20, 20.5]},
                      {"theta_i_deg": 60, "theta_r_deg": [20, 40], "phi_r_deg": 180, "polarizations": ["s"]},
                      {"theta_i_deg": 45, "grid": "paper"}]}))
    spec = load_plan(path)
    assert spec.name == "mine" and spec.n_readings == 5 and not spec.signature
    assert spec.points[:2] == (Point(60.0, "s", 20.0, 180.0), Point(60.0, "s", 40.0, 180.0))
    assert spec.points[2:6] == tuple(Point(20.0, "p", tr, 0.0) for tr in (0.0, 19.5, 20.0, 20.5))
    assert len(spec.points) == 6 + len(paper_theta_r_deg(45.0))
    assert load_plan("paper").points == tuple(paper_points())


@pytest.mark.parametrize("data, match", [
    ({"incidence": [{"theta_i_deg": 20, "theta_r": [1]}]}, r"incidence\[0\]: unknown key\(s\) theta_r"),
    ({"incidence": [{"theta_i_deg": 20}]}, r"incidence\[0\]: give exactly one of"),
    ({"incidence": [{"theta_i_deg": 95, "theta_r_deg": [1]}]}, r"incidence\[0\].theta_i_deg: 95 outside"),
    ({"incidence": [{"theta_i_deg": 20, "theta_r_deg": [1, 1]}]}, "listed twice"),
    ({"incidence": [{"theta_i_deg": 20, "theta_r_deg": [1], "phi_r_deg": 90}]}, "0 or 180"),
    ({"incidence": [], "name": "x"}, "'incidence' must be a non-empty list"),
    ({"incidence": [{"theta_i_deg": 20, "theta_r_deg": [1]}], "n_readings": 0}, "n_readings"),
    ({"incidence": [{"theta_i_deg": 20, "theta_r_deg": [1]}], "speed": 1}, r"unknown key\(s\) speed"),
    ({"incidence": [{"theta_i_deg": 20, "theta_r_deg": [1]}], "polarizations": ["u"]}, r"PBS passes s or p only"),
])
def test_plan_file_errors_name_the_entry(data, match):
    with pytest.raises(PlanError, match=match):
        plan_spec_from_dict(data, where="p.json")


def test_plan_file_json_error_has_line_and_column(tmp_path):
    path = tmp_path / "bad.json"
    path.write_text('{"incidence": [\n  {"theta_i_deg": 20,,}]}')
    with pytest.raises(PlanError, match=r"bad.json, line 2, column 22"):
        load_plan(path)
    with pytest.raises(PlanError, match="no such plan file"):
        load_plan(tmp_path / "missing.json")


def test_run_documents_carry_metadata_and_one_event_per_point(rig, new_run_engine):
    _, d = rig
    docs = []
    RE = new_run_engine()
    RE.subscribe(lambda name, doc: docs.append((name, doc)))
    points = [Point(30.0, "s", tr, 0.0) for tr in (29.0, 30.0, 31.0)]
    RE(brdf_scan(d, points, md={"sample": "z302_sample_a", "rig": {"arm_mm": "200.0"}, "plan_name": "t"}))
    names = [n for n, _ in docs]
    assert names[0] == "start" and names[-1] == "stop" and names.count("event") == 3
    start = docs[0][1]
    assert start["sample"] == "z302_sample_a" and start["plan_name"] == "t" and start["rig"]["arm_mm"] == "200.0"
    assert start["n_readings"] == 3
    events = [doc for n, doc in docs if n == "event"]
    assert [e["data"]["point_theta_r_deg"] for e in events] == [29.0, 30.0, 31.0]
    assert [e["data"]["arm"] for e in events] == [59.0, 60.0, 61.0]
    assert all(e["data"]["lockin_n"] == 3 and e["data"]["lockin_mean_v"] > 0 for e in events)
    assert docs[-1][1]["exit_status"] == "success"
