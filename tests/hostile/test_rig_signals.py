"""Hostile input: SIGINT or SIGTERM during a rig scan point with many readings stops that point before its
next reading (main 13a6b5b: a point of 1e9 readings ignored both signals). The points measured before
stay in the CSV, the stop document says 'abort' and names the signal, and --resume completes the scan."""
from __future__ import annotations

import os
import signal
import threading
import time

import pytest

from materials.scan import read_scan
from rig.plans import PlanSpec, Point
from rig.run import run_scan, sim_instrument
from rig.writer import read_log

MATERIAL = "z302_sample_a"
POINTS = tuple(Point(30.0, "s", tr, 0.0) for tr in (0.0, 10.0, 20.0, 40.0))


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_signal_inside_a_long_point_stops_it(tmp_path, signum):
    sim, dev = sim_instrument(MATERIAL, seed=1)
    readings = {"n": 0}
    real_read = dev.lockin._read_one

    def slow_read():  # a real lock-in waits several time constants per reading
        readings["n"] += 1
        if readings["n"] == 1000 + 20:  # inside the second point
            os.kill(os.getpid(), signum)
        time.sleep(0.001)
        return real_read()

    dev.lockin._read_one = slow_read
    spec = PlanSpec(name="long", points=POINTS, n_readings=1000)
    path = tmp_path / "scan.csv"
    previous = signal.getsignal(signum)
    start = time.monotonic()
    out = run_scan(dev, spec, path, sample=MATERIAL, fsync=False, handle_signals=True)
    assert time.monotonic() - start < 20
    assert signal.getsignal(signum) == previous
    assert out.exit_status == "abort" and signal.Signals(signum).name in out.reason
    assert readings["n"] <= 1000 + 20 + 100  # the second point stopped within a few readings (main: all 1000 read)
    assert len(read_scan(path)) == 1  # the first point kept
    stops = [doc for name, doc in read_log(out.log_path) if name == "stop"]
    assert stops[-1]["exit_status"] == "abort" and signal.Signals(signum).name in stops[-1]["reason"]
    dev.lockin._read_one = real_read
    out = run_scan(dev, PlanSpec(name="long", points=POINTS, n_readings=1000), path, sample=MATERIAL,
                   fsync=False, handle_signals=False, resume=True)
    assert out.exit_status == "success" and len(read_scan(path)) == len(POINTS)
    assert threading.active_count() < 50
