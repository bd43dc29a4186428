"""``rig scan --resume`` after a SIGKILL: a resume with another ``--seed`` is
refused in one line (it would mix two noise streams under the first run's header), and the killed
run gets its stop document (exit_status "abort") when the scan is opened again, so every start
document in the log has exactly one stop document, and every document validates against
event-model's schemas."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

from materials.scan import read_scan
from rig.writer import read_log
from straylight.cli.main import main

# The simulated rig takes about 4 ms a point: a long plan (about 280 points) keeps the scan running
# well past the third point, so the kill cannot race the scan's own end.
PLAN = {"name": "kill-test", "polarizations": ["s"],
        "incidence": [{"theta_i_deg": 30,
                       "theta_r_deg": [x / 4 for x in range(8, 344) if abs(x / 4 - 30) > 6]}]}


def test_killed_scan_resume_refuses_other_seed_and_closes_the_killed_run(tmp_path, capsys):
    import event_model

    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps(PLAN))
    out = tmp_path / "scan.csv"
    args = ["rig", "scan", "--sim", "--sample", "z302_sample_b", "--plan", str(plan), "-o", str(out)]
    proc = subprocess.Popen([sys.executable, "-m", "straylight.cli.main", *args, "--seed", "2"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    n = 0
    try:
        deadline = time.monotonic() + 120
        while proc.poll() is None and time.monotonic() < deadline:
            try:
                n = len(read_scan(out))
            except (ValueError, OSError):
                n = 0
            if n >= 3:
                os.kill(proc.pid, signal.SIGKILL)
                break
            time.sleep(0.02)
    finally:
        proc.wait(30)
    assert proc.returncode == -signal.SIGKILL, "the scan ended before it could be killed"
    log = out.with_name("scan.log.jsonl")
    assert [name for name, _ in read_log(log)].count("stop") == 0  # killed: no stop document yet

    assert main(args + ["--seed", "3", "--resume"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    # the killed run's lock is taken over (a warning naming its dead pid), then the seed is refused
    takeover = [e for e in err if "taking over the lock" in e]
    err = [e for e in err if e not in takeover]
    assert len(takeover) == 1 and "no longer runs" in takeover[0]
    assert len(err) == 1 and "seed" in err[0] and str(out) in err[0], err
    assert len(read_scan(out)) >= n  # nothing lost, nothing added

    assert main(args + ["--seed", "2", "--resume"]) == 0
    docs = read_log(log)
    starts = [d["uid"] for name, d in docs if name == "start"]
    stops = [d for name, d in docs if name == "stop"]
    assert len(starts) >= 2 and sorted(s["run_start"] for s in stops) == sorted(starts)
    killed = next(s for s in stops if s["run_start"] == starts[0])
    assert killed["exit_status"] == "abort" and "killed" in killed["reason"]
    assert killed["num_events"].get("primary", 0) >= 3
    assert stops[-1]["exit_status"] == "success"
    for name, doc in docs:
        event_model.schema_validators[event_model.DocumentNames[name]].validate(doc)
    scan = read_scan(out)
    assert len(scan) == len(PLAN["incidence"][0]["theta_r_deg"]) and scan.metadata["seed"] == "2"

    # settings kept only in the log's start document are checked too (the simulated rig without its
    # slit/beam averaging would continue the file with other numbers)
    capsys.readouterr()
    assert main(args + ["--seed", "2", "--resume", "--ideal"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot resume" in err[0] and "ideal" in err[0], err
