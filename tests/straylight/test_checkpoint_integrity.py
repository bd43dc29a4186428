"""Checkpoints carry a checksum and the run's parameters (item 7 for the JSON
errors): a point edited by hand (PST x1000, NaN), truncated, or of another run is refused on
resume with one line naming the file; a sweep resumed through the real ``pst`` command refuses an
edited point instead of returning its numbers."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from straylight.checkpoints import PointStore
from straylight.cli.main import main

FINGERPRINT = {"rays": 1000, "seed": 3, "angles": [0.0, 0.1]}
SCENE = Path(__file__).resolve().parents[1] / "data" / "engine_golden" / "tube.toml"


def _store_with_point(tmp_path):
    store = PointStore(tmp_path / "pts", FINGERPRINT)
    store.put(0, {"pst": 1.25e-5, "pst_se": 3.0e-7, "rays": 1000})
    return store


def test_point_round_trips_and_run_file_holds_the_parameters(tmp_path):
    _store_with_point(tmp_path)
    again = PointStore(tmp_path / "pts", FINGERPRINT, resume=True)
    assert again.get(0) == {"pst": 1.25e-5, "pst_se": 3.0e-7, "rays": 1000}
    run = json.loads((tmp_path / "pts" / "run.json").read_text())
    assert run["parameters"] == FINGERPRINT


@pytest.mark.parametrize("edit", [
    lambda v: {**v, "pst": v["pst"] * 1000},      # a hand-edited number
    lambda v: {**v, "pst": float("nan")},         # a NaN
    lambda v: {**v, "rays": 999},
])
def test_edited_point_is_refused_naming_the_file(tmp_path, edit):
    _store_with_point(tmp_path)
    path = tmp_path / "pts" / "point_000000.json"
    doc = json.loads(path.read_text())
    doc["values"] = edit(doc["values"])
    path.write_text(json.dumps(doc))
    store = PointStore(tmp_path / "pts", FINGERPRINT, resume=True)
    with pytest.raises(ValueError, match="checksum mismatch") as err:
        store.get(0)
    assert str(path) in str(err.value) and "\n" not in str(err.value)


def test_truncated_point_and_run_file_errors_name_the_file(tmp_path):
    _store_with_point(tmp_path)
    path = tmp_path / "pts" / "point_000000.json"
    path.write_text(path.read_text()[:30])
    with pytest.raises(ValueError, match="damaged") as err:
        PointStore(tmp_path / "pts", FINGERPRINT, resume=True).get(0)
    assert str(path) in str(err.value)
    run = tmp_path / "pts" / "run.json"
    run.write_text("{not json")
    with pytest.raises(ValueError, match="damaged") as err:
        PointStore(tmp_path / "pts", FINGERPRINT, resume=True)
    assert str(run) in str(err.value)


def test_point_of_another_run_or_index_is_refused(tmp_path):
    store = _store_with_point(tmp_path)
    (tmp_path / "pts" / "point_000001.json").write_text((tmp_path / "pts" / "point_000000.json").read_text())
    with pytest.raises(ValueError, match="another run or point"):
        store.get(1)
    old = tmp_path / "pts" / "point_000000.json"
    old.write_text(json.dumps({"pst": 1.0}))  # the format without a checksum
    with pytest.raises(ValueError, match="no checksum"):
        store.get(0)


def test_pst_resume_refuses_a_hand_edited_point(tmp_path, capsys):
    """The real command: points written by a sweep (the Python API keeps its folder), one edited,
    then ``straylight pst --resume`` exits 2 with one line naming the point's file."""
    from straylight.analyses.pst import pst_sweep
    from straylight.analyses.scene_setup import scene_setup
    import numpy as np

    out = tmp_path / "out"
    points = out / "pst.points"
    pst_sweep(scene_setup(str(SCENE)), np.radians([0.0, 10.0]), n_rays=2000, seed=4,
              checkpoint_dir=points)
    # the CLI sweep's fingerprint is the same as this call's (same setup, options, rays, seed)
    path = points / "point_000001.json"
    doc = json.loads(path.read_text())
    doc["values"]["values"]["pst"] *= 1000  # the PST the grid runner kept for this point
    path.write_text(json.dumps(doc))
    code = main(["pst", str(SCENE), "--angles-deg", "0", "10", "--rays", "2000", "--seed", "4",
                 "--out", str(out), "--resume"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and str(path) in err[0] and "checksum" in err[0]
    assert not (out / "pst.json").exists()


def test_a_run_without_resume_never_deletes_an_interrupted_runs_points(tmp_path):
    """Nothing measured is lost: starting the same sweep again without --resume is refused in one line naming
    --resume, and the finished point is still there to be resumed."""
    _store_with_point(tmp_path)
    with pytest.raises(ValueError, match="give --resume to keep them") as err:
        PointStore(tmp_path / "pts", FINGERPRINT)
    assert "\n" not in str(err.value) and "1 finished point" in str(err.value)
    assert PointStore(tmp_path / "pts", FINGERPRINT, resume=True).get(0)["pst"] == 1.25e-5
