"""The scan's bluesky documents (CONTRACTS 4.4), its lock-in faults, and plans that keep their data
safety under a plain ``RE(plan)``.

Documents are validated with event-model's own JSON schemas (``event_model.schema_validators``),
an independent check of what bluesky's tools (suitcase-jsonl, databroker/tiled) accept.
"""
import json
import os
import signal

import pytest
from event_model import DocumentNames, schema_validators

from materials.scan import read_scan
from rig.devices import LockinOverload, ReferenceUnlocked, real_devices
from rig.drivers import open_resource, sim_library
from rig.drivers.esp301 import Esp301
from rig.drivers.sr830 import Sr830
from rig.plans import brdf_scan
from rig.run import ScanFailed
from rig.writer import read_log
from test_faults_support import SPEC, assert_same_scan, instrument, run

MD = {"sample": "test_glossy", "plan_name": "small", "rig": {}, "gain_v_per_w": 1000.0}


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    path = tmp_path_factory.mktemp("ref") / "ref.csv"
    _, dev = instrument()
    out = run(dev, path)
    return read_scan(path), out


def validate(docs):
    for name, doc in docs:
        schema_validators[DocumentNames[name]].validate(doc)


def test_log_lines_are_name_doc_arrays_valid_under_event_model(reference):
    _, out = reference
    lines = [json.loads(line) for line in out.log_path.read_text().splitlines()]
    assert all(isinstance(x, list) and len(x) == 2 and isinstance(x[0], str) for x in lines)
    docs = read_log(out.log_path)
    validate(docs)
    names = [n for n, _ in docs]
    assert names[0] == "start" and names[-1] == "stop" and names.count("event") == len(SPEC.points)
    start = docs[0][1]
    assert start["detectors"] == ["lockin", "laser", "chopper"]
    assert start["motors"] == ["sample_stage", "arm", "hwp"]
    assert start["num_points"] == len(SPEC.points) and start["plan_args"]["n_points"] == len(SPEC.points)
    desc = next(d for n, d in docs if n == "descriptor" and d["name"] == "primary")
    # one ophyd object per device, each with its own fields
    assert set(desc["object_keys"]) == {"lockin", "laser", "chopper", "point", "sample_stage", "arm", "hwp"}
    assert desc["object_keys"]["lockin"] == ["lockin_mean_v", "lockin_std_v", "lockin_n", "lockin_discarded"]
    assert desc["object_keys"]["arm"] == ["arm", "arm_setpoint"]
    units = {k: v.get("units") for k, v in desc["data_keys"].items()}
    assert units["lockin_mean_v"] == "V" and units["laser_power_w"] == "W" and units["arm"] == "deg"
    assert units["chopper_frequency_hz"] == "Hz" and units["point_theta_r_deg"] == "deg"
    assert all("precision" in desc["data_keys"][k] for k, u in units.items() if u)
    assert set(desc["configuration"]["lockin"]["data"]) >= {"lockin_sensitivity_v", "lockin_time_constant_s"}
    assert docs[-1][1]["exit_status"] == "success"


def test_sigint_stop_document_has_abort_and_reason(tmp_path):
    _, dev = instrument()
    count = {"n": 0}

    def kill_at_4(name, doc):
        if name == "event":
            count["n"] += 1
            if count["n"] == 4:
                os.kill(os.getpid(), signal.SIGINT)

    out = run(dev, tmp_path / "i.csv", handle_signals=True, callbacks=[kill_at_4])
    docs = read_log(out.log_path)
    validate(docs)
    stop = docs[-1][1]
    assert docs[-1][0] == "stop" and stop["exit_status"] == "abort" and "SIGINT" in stop["reason"]


def test_plain_run_engine_abort_still_gives_a_reason(tmp_path, new_run_engine):
    # RE.abort(reason): bluesky's run_wrapper drops the reason; the plan's own close does not
    import threading

    from bluesky.utils import RunEngineInterrupted

    _, dev = instrument()
    RE = new_run_engine()

    def pause_at_3(name, doc, n={"n": 0}):
        n["n"] += 1
        if n["n"] == 3:
            threading.Thread(target=RE.request_pause, kwargs={"defer": True}, daemon=True).start()

    RE.subscribe(pause_at_3, "event")
    with pytest.raises(RunEngineInterrupted):
        RE(brdf_scan(dev, SPEC.points, md=MD, csv_path=tmp_path / "a.csv", fsync=False))
    RE.abort("operator")
    stop = read_log(tmp_path / "a.log.jsonl")[-1]
    assert stop[0] == "stop" and stop[1]["exit_status"] == "abort" and stop[1]["reason"]


def test_reference_unlock_waits_for_the_lock_and_remeasures(tmp_path, reference):
    ref, _ = reference
    sim, dev = instrument()
    sim.faults.reference_unlock_at_reading = 40  # mid-scan; locked again 2 s (simulated) later
    out = run(dev, tmp_path / "u.csv")
    assert out.exit_status == "success"
    assert_same_scan(read_scan(tmp_path / "u.csv"), ref)  # the unlocked reading was never used
    events = [d for n, d in read_log(out.log_path) if n == "event"]
    discarded = [e["data"]["lockin_discarded"] for e in events]
    assert sum(discarded) == 1 and discarded[0] == 0  # one reading thrown away, in one point


def test_reference_unlock_for_good_fails_with_reason_in_stop_document(tmp_path):
    sim, dev = instrument()
    sim.faults.reference_unlock_at_reading = 40
    sim.faults.reference_unlock_duration_s = float("inf")
    with pytest.raises(ScanFailed, match=r"ReferenceUnlocked: lockin: reference unlocked \(LIAS\? bit 3"):
        run(dev, tmp_path / "f.csv")
    docs = read_log(tmp_path / "f.log.jsonl")
    validate(docs)
    stop = docs[-1][1]
    assert stop["exit_status"] == "fail" and stop["reason"].startswith("ReferenceUnlocked: lockin: reference unlocked")
    assert 0 < len(read_scan(tmp_path / "f.csv")) < len(SPEC.points)  # the points before the fault are kept


def test_overload_without_autorange_fails_with_reason(tmp_path):
    sim, dev = instrument()
    dev.lockin.autorange.put(False)
    dev.lockin.sensitivity_v.put(2e-9)  # far below the signal: every reading overloads
    with pytest.raises(ScanFailed, match="LockinOverload: lockin: output overload"):
        run(dev, tmp_path / "o.csv")
    stop = read_log(tmp_path / "o.log.jsonl")[-1][1]
    assert stop["exit_status"] == "fail" and "output overload" in stop["reason"]


def _pyvisa_sim_devices(lockin_resource):
    esp = Esp301(open_resource("GPIB0::1::INSTR", visa_library=sim_library("esp301.yaml"), timeout_s=0.05))
    lia = Sr830(open_resource(lockin_resource, visa_library=sim_library("sr830.yaml"), timeout_s=0.05))
    return lia, real_devices(esp, lia)


def test_reference_unlock_reported_on_pyvisa_sim():
    lia, d = _pyvisa_sim_devices("GPIB0::11::INSTR")  # LIAS? = 8: bit 3 only
    assert lia.status_flags() == ["reference unlock"]
    d.lockin.settle_factor.put(0.0)
    d.lockin.relock_timeout_s.put(0.2)
    status = d.lockin.trigger()
    with pytest.raises(Exception):
        status.wait(5)
    assert isinstance(status.exception(), ReferenceUnlocked)
    assert "LIAS? bit 3" in str(status.exception())


def test_every_overload_bit_reported_on_pyvisa_sim():
    lia, d = _pyvisa_sim_devices("GPIB0::9::INSTR")  # LIAS? = 5: input and output overload
    assert lia.status_flags() == ["input overload", "output overload"]
    d.lockin.settle_factor.put(0.0)
    d.lockin.autorange.put(False)
    status = d.lockin.trigger()
    with pytest.raises(Exception):
        status.wait(5)
    assert isinstance(status.exception(), LockinOverload)
    assert "input overload, output overload" in str(status.exception())


def test_plain_run_engine_keeps_csv_log_and_suspender(tmp_path, reference, new_run_engine):
    # what a notebook or a queueserver does: RE(plan), nothing subscribed by hand
    ref, _ = reference
    sim, dev = instrument()
    sim.faults.laser_dip_at_reading = 7  # the plan's own SuspendFloor re-measures the point
    RE = new_run_engine()
    RE(brdf_scan(dev, SPEC.points, md=MD, csv_path=tmp_path / "nb.csv"))
    assert_same_scan(read_scan(tmp_path / "nb.csv"), ref)
    docs = read_log(tmp_path / "nb.log.jsonl")
    validate(docs)
    assert [n for n, _ in docs].count("event") == len(SPEC.points)
    assert sim.lockin.n_readings > 3 * len(SPEC.points)  # the suspension re-measured the dipped point
    assert docs[-1][1]["exit_status"] == "success"
    assert not RE._suspenders and not RE.dispatcher.cb_registry.callbacks.get("all")  # nothing left behind
    # a second RE(plan) on the same file resumes: no duplicates, nothing re-measured; devices by keyword
    RE(brdf_scan(list(SPEC.points), md=MD, csv_path=tmp_path / "nb.csv", resume=True, **dev.as_dict()))
    assert_same_scan(read_scan(tmp_path / "nb.csv"), ref)
