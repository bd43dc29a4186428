"""Hostile input: a perfect-mirror box traced with a huge --max-events grew ~20-30 MB/s until "Allocation
failed" (main 13a6b5b): the walk's tally log of a batch has a budget (a quarter of the machine's
memory); past it the trace stops with one line saying why and what to change."""
from __future__ import annotations

import time

import straylight.engine.tally_store as tally_store
from straylight.cli.main import main
from tests.hostile.test_mirror_cavity import BOX

SOURCE = """
[[source]]
type = "point"
position_mm = [5.0, 5.0, 30.0]
power_w = 1.0
"""


def test_endless_mirror_cavity_stops_at_the_budget(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(tally_store, "LOG_BUDGET_BYTES", 4 * 2**20)  # 4 MB here; a quarter of memory on a run
    scene = tmp_path / "box.toml"
    scene.write_text(BOX + SOURCE)
    start = time.monotonic()
    code = main(["trace", str(scene), "--rays", "2000", "--max-events", "1000000000", "--json", str(tmp_path / "o.json")])
    assert code == 2
    err = [line for line in capsys.readouterr().err.strip().splitlines() if "compiling" not in line]
    assert len(err) == 1 and "past the 0.00391 GB budget" in err[0] and "closed mirror cavity" in err[0], err
    assert time.monotonic() - start < 60
    assert not (tmp_path / "o.json").exists()
