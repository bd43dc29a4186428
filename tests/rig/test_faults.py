"""Faults during a scan (CONTRACTS §4.4): for each, the points measured before it are on disk and
readable (materials.scan.read_scan), the document log is complete (ends with a stop document),
and a resumed scan equals an uninterrupted one: no duplicates, no gaps, same values (the
simulated noise is keyed by position, so equality is exact)."""
import os
import signal
import threading

import pytest
from bluesky.utils import RunEngineInterrupted

from materials.scan import read_scan
from rig.devices import SoftLimitError
from rig.plans import Point, brdf_scan
from rig.run import ScanFailed
from rig.writer import CsvScanWriter, DocumentLog, read_log
from test_faults_support import SPEC, assert_same_scan, instrument, rows, run


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    path = tmp_path_factory.mktemp("ref") / "ref.csv"
    _, dev = instrument()
    run(dev, path)
    return read_scan(path)


def last_stop(log_path):
    log = read_log(log_path)
    assert log[-1][0] == "stop", "document log does not end with a stop document"
    return log[-1][1]


def test_soft_limit_rejected_before_anything_moves(tmp_path):
    from dataclasses import replace

    sim, dev = instrument()
    bad = replace(SPEC, points=SPEC.points + (Point(30.0, "s", 28.0, 180.0),))  # arm at 2 deg < 5
    with pytest.raises(SoftLimitError, match=r"theta_i 30 deg, s, theta_r 28 deg, phi_r 180 deg: arm: 2.0 deg"):
        run(dev, tmp_path / "s.csv", spec=bad)
    assert all(ax.n_moves == 0 for ax in sim.axes.values())
    assert not (tmp_path / "s.csv").exists()


def test_soft_limit_inside_a_running_plan_keeps_earlier_points(tmp_path, reference, new_run_engine):
    # bypass the pre-flight check: the device itself refuses, before motion
    sim, dev = instrument()
    path = tmp_path / "s.csv"
    writer, log = CsvScanWriter(path), DocumentLog(tmp_path / "s.log.jsonl", fsync=False)
    RE = new_run_engine()
    RE.subscribe(log)
    RE.subscribe(writer)
    points = SPEC.points[:4] + (Point(30.0, "s", 28.0, 180.0),) + SPEC.points[4:]
    md = {"sample": "test_glossy", "plan_name": "small", "rig": {}, "gain_v_per_w": 1000.0}
    with pytest.raises(SoftLimitError):  # the plan checks every point when it is built
        brdf_scan(dev, points, md=md)
    with pytest.raises(Exception) as info:
        RE(brdf_scan(dev, points, md=md, check_limits=False))
    assert "outside the soft limits" in str(info.value)
    assert sim.axes["arm"].position() != 2.0
    assert len(read_scan(path)) == 4
    assert last_stop(tmp_path / "s.log.jsonl")["exit_status"] == "fail"
    run(dev, path, resume=True)
    assert_same_scan(read_scan(path), reference)


@pytest.mark.parametrize("fault", ["stalled_move", "lockin_timeout"])
def test_device_fault_keeps_points_and_resume_completes(tmp_path, reference, fault):
    sim, dev = instrument()
    path = tmp_path / "f.csv"
    callbacks = []
    if fault == "stalled_move":
        sim.axes["arm"].stall_after_moves = 7  # the 8th arm move never finishes
        match = r"MoveTimeout: arm: move to .* not finished"
    else:
        def after_4_points(name, doc):
            if name == "event" and len(read_scan(path)) == 4:
                sim.faults.lockin_timeout_at_reading = 0  # every reading from now on times out

        callbacks.append(after_4_points)
        match = r"InstrumentTimeout: simulated SR830: no reply"
    with pytest.raises(ScanFailed, match=match) as info:
        run(dev, path, callbacks=callbacks)
    assert "rerun with --resume" in str(info.value)
    partial = read_scan(path)
    expected_rows = 7 if fault == "stalled_move" else 4
    assert len(partial) == expected_rows > 0
    ref = rows(reference)
    assert all(ref[k] == pytest.approx(v, rel=1e-12) for k, v in rows(partial).items())  # saved rows are right
    assert last_stop(path.with_name("f.log.jsonl"))["exit_status"] == "fail"
    # the operator fixes the fault and resumes
    sim.axes["arm"].stall_after_moves = None
    sim.axes["arm"].stalled = False
    sim.faults.lockin_timeout_at_reading = None
    out = run(dev, path, resume=True)
    assert out.exit_status == "success" and out.n_measured == len(SPEC.points) - expected_rows
    assert_same_scan(read_scan(path), reference)


def test_laser_dip_suspends_and_remeasures(tmp_path, reference):
    sim, dev = instrument()
    sim.faults.laser_dip_at_reading = 7  # 2nd reading of the 3rd point, power to 5 % for 0.2 s
    out = run(dev, tmp_path / "d.csv")
    assert out.exit_status == "success"
    assert sim.lockin.n_readings > 3 * len(SPEC.points)  # sanity: the point was re-measured
    assert_same_scan(read_scan(tmp_path / "d.csv"), reference)
    assert last_stop(out.log_path)["exit_status"] == "success"


def _pause_at(RE, n_events):
    """Request a pause after ``n_events`` events, from another thread, as an operator would
    (request_pause blocks until the RunEngine's own thread acknowledges)."""
    count = {"n": 0}

    def cb(name, doc):
        count["n"] += 1
        if count["n"] == n_events:
            threading.Thread(target=RE.request_pause, kwargs={"defer": True}, daemon=True).start()

    return cb


def test_operator_pause_resume_and_abort(tmp_path, reference, new_run_engine):
    md = {"sample": "test_glossy", "plan_name": "small", "rig": {}, "gain_v_per_w": 1000.0}
    for action in ("resume", "abort"):
        _, dev = instrument()
        path = tmp_path / f"{action}.csv"
        RE = new_run_engine()
        log = DocumentLog(tmp_path / f"{action}.log.jsonl", fsync=False)
        RE.subscribe(log)
        RE.subscribe(CsvScanWriter(path))
        RE.subscribe(_pause_at(RE, 5), "event")
        with pytest.raises(RunEngineInterrupted):
            RE(brdf_scan(dev, SPEC.points, md=md))
        assert RE.state == "paused"
        n_saved = len(read_scan(path))
        assert 5 <= n_saved < len(SPEC.points)
        if action == "resume":
            RE.resume()
            assert_same_scan(read_scan(path), reference)
        else:
            RE.abort("operator")
            assert len(read_scan(path)) == n_saved
            assert last_stop(tmp_path / "abort.log.jsonl")["exit_status"] == "abort"
            run(dev, path, resume=True)
            assert_same_scan(read_scan(path), reference)


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_signal_stops_cleanly_and_resume_completes(tmp_path, reference, signum):
    _, dev = instrument()
    path = tmp_path / "sig.csv"
    count = {"n": 0}

    def kill_at_6(name, doc):
        if name == "event":
            count["n"] += 1
            if count["n"] == 6:
                os.kill(os.getpid(), signum)

    previous = signal.getsignal(signum)
    out = run(dev, path, handle_signals=True, callbacks=[kill_at_6])
    assert signal.getsignal(signum) == previous  # handlers restored
    assert out.exit_status == "abort" and signal.Signals(signum).name in out.reason
    partial = read_scan(path)
    assert 6 <= len(partial) < len(SPEC.points)
    assert last_stop(out.log_path)["exit_status"] == "abort"
    out = run(dev, path, resume=True)
    assert out.exit_status == "success"
    assert_same_scan(read_scan(path), reference)
