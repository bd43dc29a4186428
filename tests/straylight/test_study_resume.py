"""Resumable studies: a study interrupted by Ctrl-C inside its design sweep leaves a
readable partial report naming the missing steps and exits 130; ``--resume`` reads the finished PST
and sweep points back (not traced again) and ends with the same results.json numbers as a study
that ran straight through (wall-clock fields aside); a resume with other settings is refused."""
from __future__ import annotations

import json

import straylight.analyses.sweep as sweep_mod
from straylight.cli.main import main

ARGS = ["study", "--rays", "1000", "--seed", "3", "--angles-deg", "0", "20", "--sweep-values", "0", "7"]


def _numbers(doc):
    """results.json without wall-clock fields (timings, per-point seconds)."""
    doc = {k: v for k, v in doc.items() if k != "timings_s"}
    for key in ("pst", "sweep"):
        doc[key] = {**doc[key], "points": [{k: v for k, v in p.items() if k != "seconds"} for p in doc[key]["points"]]}
    return doc


def test_interrupted_study_resumes_to_the_same_numbers(tmp_path, monkeypatch, capsys):
    straight = tmp_path / "straight"
    assert main(ARGS + ["--out", str(straight)]) == 0
    assert not (straight / "study.points").exists()  # removed once the report is written

    # Ctrl-C while the sweep builds its second design (its first design's points are finished)
    out = tmp_path / "resumed"
    real_build, calls = sweep_mod.tube_setup, []

    def interrupt_second_design(**params):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real_build(**params)

    monkeypatch.setattr(sweep_mod, "tube_setup", interrupt_second_design)
    assert main(ARGS + ["--out", str(out)]) == 130
    monkeypatch.undo()
    partial = json.loads((out / "results.json").read_text())
    assert partial["status"] == "interrupted"
    assert partial["completed_steps"] == ["geometry", "pst", "paths", "critical"]
    assert partial["missing_steps"] == ["sweep", "views", "report"]
    assert partial["finished_sweep_points"] == {"pst": 2, "sweep": 2}  # 2 PST angles; design 0 at 20 and 30 deg
    page = (out / "index.html").read_text()
    assert "Missing steps: sweep, views, report" in page and "--resume" in page
    assert 'href="pst.json"' in page
    pst_seconds = [p["seconds"] for p in json.loads((out / "pst.json").read_text())["points"]]
    capsys.readouterr()

    # other settings: refused in one line, the finished points are kept
    other = [a if a != "3" else "4" for a in ARGS]
    assert main(other + ["--out", str(out), "--resume"]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if not line.startswith("[study]")]
    assert len(err) == 1 and "holds points of a different run" in err[0], err
    assert len(list((out / "study.points" / "sweep").glob("point_*.json"))) == 2

    assert main(ARGS + ["--out", str(out), "--resume"]) == 0
    resumed = json.loads((out / "results.json").read_text())
    assert _numbers(resumed) == _numbers(json.loads((straight / "results.json").read_text()))
    # the PST points were read back, not traced again: their recorded times are the interrupted run's
    assert [p["seconds"] for p in resumed["pst"]["points"]] == pst_seconds
    assert not (out / "study.points").exists()
