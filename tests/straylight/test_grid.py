"""The one grid runner (straylight.analyses.grid): a resumed grid returns the floats of an
uninterrupted one, a precision target stops each point by its rule, progress reaches stderr, and a
checkpoint written by an earlier version is refused in one line."""
from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from straylight.analyses.grid import GridPoint, open_checkpoint, point_seed, run_grid
from straylight.analyses.precision import Precision
from straylight.analyses.pst import detector_area, detector_name, pst_job, pst_options
from straylight.analyses.scene_setup import scene_setup
from straylight.checkpoints import PointStore
from straylight.cli.main import main
from straylight.execution import Execution

SCENE = Path(__file__).resolve().parents[1] / "data" / "engine_golden" / "tube.toml"
ANGLES_DEG = (0.0, 10.0, 20.0)


@pytest.fixture(scope="module")
def grid():
    """(points, job) of a three-angle PST grid on the golden tube."""
    setup = scene_setup(str(SCENE))
    det = detector_name(setup.scene, setup.detector)
    area = detector_area(setup, det).area_mm2
    opts = pst_options(True)
    points = [GridPoint(i, point_seed(4, i), f"{a:g} deg") for i, a in enumerate(ANGLES_DEG)]

    def job(point):
        return pst_job(setup, det, area, math.radians(ANGLES_DEG[point.key]), 0.0, opts)

    return points, job


def _floats(runs):
    return [(r.values, r.rays, r.diagnostics) for r in runs]


def test_resumed_grid_returns_the_numbers_of_an_uninterrupted_one(grid, tmp_path):
    points, job = grid
    straight = run_grid(points, job, rays=2000)
    assert all(r.values["pst"] > 0 for r in straight)  # light reaches the detector: not 0 == 0

    calls = []

    def failing(point):
        calls.append(point.key)
        if point.key == 2:
            raise KeyboardInterrupt  # Ctrl-C while the third point is set up
        return job(point)

    fp = {"grid": "test", "rays": 2000}
    with pytest.raises(KeyboardInterrupt):
        run_grid(points, failing, rays=2000, checkpoint=open_checkpoint(tmp_path / "pts", fp))
    assert calls == [0, 1, 2]
    calls.clear()
    again = run_grid(points, lambda p: calls.append(p.key) or job(p), rays=2000,
                     checkpoint=open_checkpoint(tmp_path / "pts", fp, resume=True))
    assert calls == [2]  # the two finished points are read back, not traced
    assert _floats(again) == _floats(straight)  # bit for bit (floats through JSON by repr)


def test_a_point_tagged_for_another_layout_is_traced_again(grid, tmp_path):
    points, job = grid
    store = open_checkpoint(tmp_path / "pts", {"grid": "tag"})
    run_grid(points[:1], job, rays=1000, checkpoint=store)
    calls = []
    other = [GridPoint(0, points[0].seed, "0 deg", tag=[1.0, 2.0])]
    run_grid(other, lambda p: calls.append(p.key) or job(p), rays=1000,
             checkpoint=open_checkpoint(tmp_path / "pts", {"grid": "tag"}, resume=True))
    assert calls == [0]


def test_precision_target_stops_each_point_by_its_rule(grid):
    points, job = grid
    reached = run_grid(points[:1], job, precision=Precision(0.2, first_rays=1000))[0]
    assert reached.diagnostics["stop_reason"] == "target"
    assert reached.values["pst_stderr"] / reached.values["pst"] <= 0.2
    capped = run_grid(points[:1], job, precision=Precision(0.001, max_rays=3000, first_rays=1000))[0]
    assert capped.diagnostics["stop_reason"] == "max_rays" and capped.rays == 3000
    timed = run_grid(points[:1], job, precision=Precision(0.001, max_seconds=1e-6, first_rays=1000))[0]
    assert timed.diagnostics["stop_reason"] == "max_seconds" and timed.rays == 1000


def test_progress_reaches_stderr(grid, capsys, monkeypatch):
    points, job = grid
    monkeypatch.setenv("STRAYLIGHT_PROGRESS_INTERVAL_S", "0.001")  # a line per step in a log (not a terminal)
    run_grid(points[:2], job, Execution(progress=True), rays=1000, desc="grid under test")
    err = capsys.readouterr().err
    assert "grid under test" in err and "/2" in err
    run_grid(points[:1], job, Execution(), rays=1000, desc="quiet grid")
    assert "quiet grid" not in capsys.readouterr().err


def test_checkpoint_of_an_earlier_version_is_refused_in_one_line(tmp_path, capsys):
    """A pst.points folder as the sweeps wrote it before the grid runner (run.json without "format",
    points holding pst values directly): --resume refuses it with one line, no traceback."""
    folder = tmp_path / "out" / "pst.points"
    folder.mkdir(parents=True)
    (folder / "run.json").write_text(json.dumps({"fingerprint_sha256": "0" * 64, "parameters": {}}))
    (folder / "point_000000.json").write_text(json.dumps({"index": 0, "run_sha256": "0" * 64, "sha256": "0" * 64,
                                                          "values": {"pst": 1e-5, "pst_se": 1e-7}}))
    with pytest.raises(ValueError, match="another version of straylight .checkpoint format 1, this one reads 2"):
        PointStore(folder, {"any": 1}, resume=True)
    rc = main(["pst", str(SCENE), "--angles-deg", "0", "--rays", "1000", "--out", str(tmp_path / "out"), "--resume"])
    err = capsys.readouterr().err.strip()
    assert rc != 0 and len(err.splitlines()) == 1 and "another version of straylight" in err
    assert "Traceback" not in err


def test_each_point_says_which_strategies_did_not_run_and_why(grid, tmp_path):
    """A point's diagnostics carry its trace's plan (the strategies asked for that did not run, with the
    plan's reason: on the golden tube, which has no glass, the eye chains); pst.json keeps them per point,
    pst.csv keeps its columns."""
    import numpy as np

    from straylight.analyses.types import CSV_COLUMNS, PstResult

    points, job = grid
    run = run_grid(points[:1], job, rays=1000)[0]
    off = run.diagnostics["strategies_off"]
    assert "no interface" in off["reverse_chain"], off
    ones = np.ones(1)
    res = PstResult(off_axis_deg=ones * 0.0, azimuth_deg=ones * 0.0, pst=ones * 1e-5, pst_stderr=ones * 1e-7,
                    entrance_ratio=ones, entrance_ratio_stderr=ones * 0.01, detector_w=ones,
                    detector_stderr_w=ones * 0.01, seconds=ones, rays=1000, seed=0, nee=True, detector="det",
                    detector_area_mm2=1.0, beam_power_w=1.0, diagnostics=[run.diagnostics])
    doc = json.loads(res.write_json(tmp_path / "pst.json").read_text())
    assert doc["points"][0]["strategies_off"] == off
    header = (res.write_csv(tmp_path / "pst.csv")).read_text().splitlines()[0].split(",")
    assert "strategies_off" not in header and header[:len(CSV_COLUMNS)] == list(CSV_COLUMNS)
