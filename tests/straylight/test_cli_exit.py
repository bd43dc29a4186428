"""The ``straylight`` command skips the garbage collections of the interpreter's shutdown
(straylight.cli.main._no_collection_at_exit): a third of a CPU second after a ``pst`` run."""
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

