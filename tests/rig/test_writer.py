"""Document log + incremental atomic CSV + resume (CONTRACTS §2, §4.4)."""
import json
import math

import numpy as np
import pytest

from materials.lambertian import Lambertian
from materials.scan import read_scan
from rig.devices import sim_devices
from rig.run import run_scan
from rig.sim import SimRig
from rig.writer import DocumentLog, ResumeError, brdf_from_reading, read_log
from test_faults_support import SPEC, assert_same_scan, instrument, rows, run


def test_brdf_from_reading_is_the_calibration_equation():
    # BRDF = P_s / (P_i Omega cos theta_r), P_s = V / g (seed paper section 2)
    brdf, std = brdf_from_reading(2e-3, 1e-4, 5e-3, 60.0, gain_v_per_w=100.0, solid_angle_sr=2.5e-5)
    assert brdf == pytest.approx(2e-3 / 100.0 / (5e-3 * 2.5e-5 * 0.5))
    assert std == pytest.approx(brdf / 20)
    assert math.isnan(brdf_from_reading(1.0, 0.0, 0.0, 10.0, 1.0, 1.0)[0])


def test_noise_free_lambertian_scan_reads_rd_over_pi(tmp_path):
    # the whole chain (sim lock-in volts -> event -> CSV) returns f = rd / pi for a Lambertian
    sim = SimRig(Lambertian(0.2), seed=0, ideal=True, noise_rel=0.0, noise_floor_per_sr=0.0)
    out = run_scan(sim_devices(sim), SPEC, tmp_path / "lam.csv", sample="lam", fsync=False, handle_signals=False)
    scan = read_scan(tmp_path / "lam.csv")
    assert out.exit_status == "success" and len(scan) == len(SPEC.points) == out.n_measured
    np.testing.assert_allclose(scan.brdf_per_sr, 0.2 / np.pi, rtol=1e-12)
    assert np.all(scan.brdf_std_per_sr <= 1e-12 * scan.brdf_per_sr) and np.all(scan.n_repeats == 3)
    assert scan.metadata["sample"] == "lam" and scan.metadata["rig.arm_mm"] == "200.0"
    assert scan.metadata["rig.slit_width_mm"] == "0.2" and "date" in scan.metadata


def test_csv_valid_after_every_point_and_log_complete(tmp_path):
    sim, dev = instrument()
    path = tmp_path / "scan.csv"
    seen = []

    def check(name, doc):  # subscribed after the writer: sees the file as left after each point
        if name == "event":
            seen.append(len(read_scan(path)))

    out = run(dev, path, callbacks=[check], fsync=True)
    assert seen == list(range(1, len(SPEC.points) + 1))
    assert out.n_points_in_file == len(SPEC.points)
    log = read_log(out.log_path)
    names = [n for n, _ in log]
    assert names[0] == "start" and names[-1] == "stop" and names.count("event") == len(SPEC.points)
    assert log[-1][1]["exit_status"] == "success"
    assert log[0][1]["sample"] == "test_glossy" and log[0][1]["plan_name"] == "small"
    # every line of the log is standalone JSON
    for line in out.log_path.read_text().splitlines():
        json.loads(line)
    assert not list(tmp_path.glob(".*.tmp"))  # no temp files left behind


def test_existing_file_is_never_overwritten(tmp_path):
    _, dev = instrument()
    path = tmp_path / "scan.csv"
    run(dev, path)
    before = path.read_text()
    with pytest.raises(ResumeError, match="already exists; use --resume"):
        run(dev, path)
    assert path.read_text() == before


def test_resume_of_complete_scan_adds_nothing(tmp_path):
    _, dev = instrument()
    path = tmp_path / "scan.csv"
    run(dev, path)
    before = read_scan(path)
    out = run(dev, path, resume=True)
    assert out.exit_status == "success" and out.n_measured == 0
    assert_same_scan(read_scan(path), before)
    assert [n for n, _ in read_log(out.log_path)].count("start") == 2  # the log keeps both runs


def test_resume_refuses_another_sample(tmp_path):
    _, dev = instrument()
    path = tmp_path / "scan.csv"
    run(dev, path)
    with pytest.raises(ResumeError, match="file has sample 'test_glossy', this scan 'other'"):
        run_scan(dev, SPEC, path, sample="other", resume=True, fsync=False, handle_signals=False)


def test_document_log_appends_and_serialises_numpy(tmp_path):
    log = DocumentLog(tmp_path / "l.jsonl")
    log("start", {"uid": "a", "x": np.float64(1.5), "arr": np.arange(3)})
    log = DocumentLog(tmp_path / "l.jsonl")
    log("stop", {"uid": "b"})
    assert read_log(tmp_path / "l.jsonl") == [("start", {"uid": "a", "x": 1.5, "arr": [0, 1, 2]}), ("stop", {"uid": "b"})]


def test_same_seed_same_numbers_any_point_order(tmp_path):
    # noise keyed by (seed, position, reading): reversing the plan changes nothing
    from dataclasses import replace

    _, dev = instrument(seed=5)
    run(dev, tmp_path / "a.csv")
    _, dev2 = instrument(seed=5)
    run(dev2, tmp_path / "b.csv", spec=replace(SPEC, points=tuple(reversed(SPEC.points))))
    assert_same_scan(read_scan(tmp_path / "a.csv"), read_scan(tmp_path / "b.csv"))
    _, dev3 = instrument(seed=6)
    run(dev3, tmp_path / "c.csv")
    a, c = rows(read_scan(tmp_path / "a.csv")), rows(read_scan(tmp_path / "c.csv"))
    assert any(a[k][0] != c[k][0] for k in a)
