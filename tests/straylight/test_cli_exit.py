"""The ``straylight`` command skips the garbage collections of the interpreter's shutdown
(straylight.cli.main._no_collection_at_exit) and runs fewer full collections during a command."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_the_command_freezes_the_collector_at_exit():
    # atexit runs its handlers last-registered first: this one, registered before main(), sees the state
    # the interpreter's shutdown starts from
    code = ("import atexit, gc\n"
            "atexit.register(lambda: print('frozen objects at exit:', gc.get_freeze_count()))\n"
            "from straylight.cli.main import main\n"
            "main([])\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT).stdout
    count = int(out.rsplit("frozen objects at exit:", 1)[1].split()[0])
    assert count > 1000, out[-300:]



def test_full_collections_are_rarer_during_a_command_and_restored_after(monkeypatch, tmp_path):
    import gc

    import straylight.cli.pst
    from straylight.cli.main import main

    seen = []
    monkeypatch.setattr(straylight.cli.pst, "run", lambda args: seen.append(gc.get_threshold()) or 0)
    before = gc.get_threshold()
    assert main(["pst", "--builtin", "tube", "--rays", "10", "--out", str(tmp_path / "out")]) == 0
    assert seen and seen[0][:2] == before[:2] and seen[0][2] >= 100  # the young generations as before
    assert gc.get_threshold() == before
