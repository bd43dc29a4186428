"""Resumable PST sweeps: a sweep killed after some points and continued with --resume
ends with the same pst.json as one that ran straight through (wall-clock ``seconds`` aside), and
the finished points are read back, not traced again."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from straylight.cli.main import main

SCENE = Path(__file__).resolve().parents[1] / "data" / "engine_golden" / "tube.toml"
ARGS = ["pst", str(SCENE), "--angles-deg", "0", "10", "20", "30", "--rays", "3000", "--seed", "4"]


def _numbers(doc):
    """pst.json without the wall-clock seconds of each point."""
    return {**doc, "points": [{k: v for k, v in p.items() if k != "seconds"} for p in doc["points"]]}


def test_interrupted_sweep_resumed_gives_the_same_json(tmp_path, capsys):
    straight = tmp_path / "straight"
    assert main(ARGS + ["--out", str(straight)]) == 0
    assert not (straight / "pst.points").exists()  # removed once the results are written

    out = tmp_path / "resumed"
    points = out / "pst.points"
    proc = subprocess.Popen([sys.executable, "-m", "straylight.cli.main", *ARGS, "--out", str(out)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 300
        while not (points / "point_000000.json").exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.01)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(30)
    assert proc.returncode == -signal.SIGKILL, "the sweep finished before it could be interrupted"
    done = sorted(points.glob("point_*.json"))
    assert 1 <= len(done) < 4 and not (out / "pst.json").exists()
    seconds_done = [json.loads(p.read_text())["values"]["seconds"] for p in done]

    # another seed: refused in one line, the points are kept
    assert main(ARGS[:-1] + ["5", "--out", str(out), "--resume"]) == 2
    assert "holds points of a different run" in capsys.readouterr().err
    assert len(list(points.glob("point_*.json"))) == len(done)

    assert main(ARGS + ["--out", str(out), "--resume"]) == 0
    resumed = json.loads((out / "pst.json").read_text())
    assert _numbers(resumed) == _numbers(json.loads((straight / "pst.json").read_text()))
    # the finished points were read back, not traced again: their recorded times are the killed run's
    assert [p["seconds"] for p in resumed["points"][:len(done)]] == seconds_done
    assert not points.exists()
