"""One bluesky RunEngine per process: scans share it, so the thread count does not grow scan after
scan (a RunEngine made per scan left its event-loop thread behind every time), and stopping it
joins its thread."""
import threading

import numpy as np

from materials.lambertian import Lambertian
from materials.scan import read_scan
from rig.devices import sim_devices
from rig.run import run_scan, session_run_engine, stop_session_run_engine
from rig.sim import SimRig
from test_faults_support import SPEC


def _scan(path):
    sim = SimRig(Lambertian(0.2), seed=0, ideal=True, noise_rel=0.0, noise_floor_per_sr=0.0)
    return run_scan(sim_devices(sim), SPEC, path, sample="lam", fsync=False, handle_signals=False)


def test_scans_share_one_run_engine_and_leave_no_threads(tmp_path):
    _scan(tmp_path / "0.csv")
    engine = session_run_engine()
    after_first = threading.active_count()
    for i in range(1, 4):
        assert _scan(tmp_path / f"{i}.csv").exit_status == "success"
        assert session_run_engine() is engine
    assert threading.active_count() == after_first, [t.name for t in threading.enumerate()]
    # each scan's file as from a fresh engine: same rows, the Lambertian's rd / pi
    first, last = read_scan(tmp_path / "0.csv"), read_scan(tmp_path / "3.csv")
    np.testing.assert_array_equal(first.brdf_per_sr, last.brdf_per_sr)
    np.testing.assert_allclose(last.brdf_per_sr, 0.2 / np.pi, rtol=1e-12)


def test_stopping_the_session_engine_joins_its_thread(tmp_path):
    engine = session_run_engine()
    thread = engine._th
    assert thread.is_alive()
    stop_session_run_engine()
    assert not thread.is_alive() and engine.loop.is_closed()
    again = session_run_engine()  # a later scan makes a new one
    assert again is not engine and again._th.is_alive()
    assert _scan(tmp_path / "after.csv").exit_status == "success"
