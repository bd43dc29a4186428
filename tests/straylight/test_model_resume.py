"""Resumable ``study --model FILE.py:build``: a study interrupted by Ctrl-C inside its
model sweep leaves a readable partial report and keeps the finished sweep points; ``--resume``
reads them back (the finished design is not built or traced again) and ends with the same
results.json numbers as a study that ran straight through (wall-clock fields aside); an edited
model file is a different run and is refused."""
from __future__ import annotations

import json

import pytest

import straylight.analyses.model as model_mod
from straylight.cli.main import main
from test_model_sweep import MODEL
from test_study_resume import _numbers


@pytest.fixture()
def model(tmp_path):
    path = tmp_path / "aperture.py"
    path.write_text(MODEL)
    return path


def _args(model, out):
    return ["study", "--model", f"{model}:build", "--sweep-parameter", "hole_radius_mm", "--sweep-values", "4", "6",
            "--rays", "1000", "--seed", "5", "--angles-deg", "0", "10", "--path-angle-deg", "10", "--out", str(out)]


def _counting_designs(monkeypatch, fail_at=None):
    """Count model builds (the study's own design first, then one per swept design still to trace);
    raise KeyboardInterrupt at build number ``fail_at``."""
    real, calls = model_mod.design_scene, []

    def design_scene(model, params, directory):
        calls.append(dict(params))
        if len(calls) == fail_at:
            raise KeyboardInterrupt
        return real(model, params, directory)

    monkeypatch.setattr(model_mod, "design_scene", design_scene)
    return calls


def test_interrupted_model_study_resumes_to_the_same_numbers(model, tmp_path, monkeypatch, capsys):
    straight = tmp_path / "straight"
    assert main(_args(model, straight)) == 0
    assert not (straight / "study.points").exists()

    out = tmp_path / "resumed"
    _counting_designs(monkeypatch, fail_at=3)  # Ctrl-C while building the second swept design
    assert main(_args(model, out)) == 130
    monkeypatch.undo()
    partial = json.loads((out / "results.json").read_text())
    assert partial["status"] == "interrupted"
    assert partial["missing_steps"] == ["sweep", "views", "report"]
    assert partial["finished_sweep_points"] == {"pst": 2, "sweep": 2}  # design R=4 at both sweep angles
    assert "Missing steps: sweep, views, report" in (out / "index.html").read_text()
    capsys.readouterr()

    # an edited model file is another run: refused in one line, the finished points are kept
    original = model.read_text()
    model.write_text(original + "\n# edited\n")
    assert main(_args(model, out) + ["--resume"]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.startswith("straylight: error")]
    assert len(err) == 1 and "holds points of a different run" in err[0], err
    assert len(list((out / "study.points" / "sweep").glob("point_*.json"))) == 2
    model.write_text(original)

    calls = _counting_designs(monkeypatch)
    assert main(_args(model, out) + ["--resume"]) == 0
    assert calls == [{}, {"hole_radius_mm": 6}]  # the finished design R=4 was not built again
    # the same numbers; the report folder's name appears in the scene paths
    resumed = json.loads((out / "results.json").read_text().replace(str(out), "OUT"))
    assert _numbers(resumed) == _numbers(json.loads((straight / "results.json").read_text().replace(str(straight), "OUT")))
    assert not (out / "study.points").exists()
