"""``straylight design vanes --resume``: a run interrupted during its final PST
evaluations, resumed, writes the same design.json as one run straight through (wall-clock
``seconds`` aside) and traces only the points that were missing."""
from __future__ import annotations

import json

import straylight.analyses.grid as trace_mod  # the grid runner traces every point
from straylight.cli.main import main

ARGS = ["design", "vanes", "--tube-radius-mm", "50", "--tube-length-mm", "300", "--stop-radius-mm", "35",
        "--field-deg", "0.5", "--exclusion-deg", "20", "--rays", "2000", "--refine-evals", "0", "--seed", "2",
        "--threads", "1"]


def _counting(monkeypatch, fail_at=None):
    real, calls = trace_mod.trace, []

    def trace(*args, **kwargs):
        calls.append(1)
        if len(calls) == fail_at:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(trace_mod, "trace", trace)
    return calls


def test_interrupted_design_resumes_to_the_same_json(tmp_path, monkeypatch):
    straight = tmp_path / "straight"
    calls = _counting(monkeypatch)
    assert main(ARGS + ["--out", str(straight)]) == 0
    n_total = len(calls)  # construction, evenly spaced baseline, no vanes: each at every band angle
    assert n_total % 3 == 0 and not (straight / "design.points").exists()
    n_angles = n_total // 3

    out = tmp_path / "resumed"
    monkeypatch.undo()
    _counting(monkeypatch, fail_at=n_angles + 2)  # Ctrl-C inside the baseline's evaluation
    assert main(ARGS + ["--out", str(out)]) == 130
    assert len(list((out / "design.points").glob("point_*.json"))) == n_angles + 1
    assert not (out / "design.json").exists()

    monkeypatch.undo()
    assert main([a if a != "2000" else "3000" for a in ARGS] + ["--out", str(out), "--resume"]) == 2  # other rays

    monkeypatch.undo()
    calls = _counting(monkeypatch)
    assert main(ARGS + ["--out", str(out), "--resume"]) == 0
    assert len(calls) == n_total - (n_angles + 1)  # the finished points were read back
    doc, ref = (json.loads((d / "design.json").read_text()) for d in (out, straight))
    doc.pop("seconds"), ref.pop("seconds")
    assert doc == ref
    assert not (out / "design.points").exists()


def test_resume_keeps_a_design_the_user_edited(tmp_path, capsys):
    """``--resume`` does not replace a design.json (or scene.toml) the user edited since the run wrote it:
    refused in one line naming the file, the edit kept; ``--force`` replaces it. What an interrupted run
    wrote before it stopped stays its own (a resume replaces it without --force)."""
    out = tmp_path / "d"
    assert main(ARGS + ["--out", str(out)]) == 0
    design = out / "design.json"
    edited = design.read_text().replace('"design_source"', '"my_note": "hand-tuned", "design_source"')
    design.write_text(edited)
    capsys.readouterr()
    assert main(ARGS + ["--out", str(out), "--resume"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "design.json" in err and "--force" in err, err
    assert design.read_text() == edited
    assert main(ARGS + ["--out", str(out), "--resume", "--force"]) == 0
    assert "my_note" not in design.read_text()


def test_an_interrupted_runs_own_files_are_resumed_without_force(tmp_path, monkeypatch):
    out = tmp_path / "d"
    import straylight.design.vanes as vanes_mod

    real = vanes_mod.write_report

    def stop(*args, **kwargs):  # Ctrl-C after scene.toml and design.step are written, before design.json
        raise KeyboardInterrupt

    monkeypatch.setattr(vanes_mod, "write_report", stop)
    assert main(ARGS + ["--out", str(out)]) == 130
    assert (out / "scene.toml").exists() and not (out / "design.json").exists()
    monkeypatch.setattr(vanes_mod, "write_report", real)
    assert main(ARGS + ["--out", str(out), "--resume"]) == 0
    assert (out / "design.json").exists()
