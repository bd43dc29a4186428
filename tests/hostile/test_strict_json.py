"""CONTRACTS 1: every JSON file the commands write is strict RFC 8259 JSON. A value that is not
a finite number is ``null``; ``NaN`` / ``Infinity`` never appear. Each command is run, then every
``*.json`` / ``*.jsonl`` file under its output is parsed with a parser that refuses the three
non-standard constants (``json.loads`` calls ``parse_constant`` only for them)."""
from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

import atomicio
from straylight.cli.main import main


def _refuse(name):
    raise ValueError(f"non-standard JSON constant {name}")


def strict_load(text: str):
    return json.loads(text, parse_constant=_refuse)


def strict_files(root: Path) -> list[Path]:
    """Parse every JSON / JSON-lines file under ``root`` strictly; returns the files read."""
    files = sorted(p for p in root.rglob("*") if p.is_file() and p.suffix in (".json", ".jsonl"))
    for path in files:
        text = path.read_text(encoding="utf-8")
        try:
            if path.suffix == ".jsonl":
                for line in text.splitlines():
                    strict_load(line)
            else:
                strict_load(text)
        except ValueError as exc:
            pytest.fail(f"{path.relative_to(root)} is not strict JSON: {exc}")
    return files


def test_the_strict_parser_refuses_nan():
    with pytest.raises(ValueError):
        strict_load('{"a": NaN}')
    with pytest.raises(ValueError):
        strict_load('[Infinity]')
    assert strict_load('{"a": null}') == {"a": None}


def test_writers_write_null_for_non_finite(tmp_path):
    doc = {"a": float("nan"), "b": [float("inf"), -float("inf"), 1.5]}
    atomicio.write_json(tmp_path / "x.json", doc, allow_nan=True)  # the old non-strict switch is ignored
    atomicio.append_json_line(tmp_path / "x.jsonl", doc)
    assert strict_load((tmp_path / "x.json").read_text()) == {"a": None, "b": [None, None, 1.5]}
    assert strict_load((tmp_path / "x.jsonl").read_text()) == {"a": None, "b": [None, None, 1.5]}


def test_result_files_mixin_is_strict(tmp_path):
    from straylight.analyses.tables import ResultFiles

    class R(ResultFiles):
        def to_json_dict(self):
            return {"pst": float("nan"), "vov": float("inf")}

    R().write_json(tmp_path / "r.json")
    assert strict_load((tmp_path / "r.json").read_text()) == {"pst": None, "vov": None}


def test_checkpoint_points_are_strict_and_round_trip_nan(tmp_path):
    from straylight.checkpoints import PointStore

    store = PointStore(tmp_path / "pts", {"x": 1})
    store.put(0, {"values": {"pst": 0.0, "rel": float("nan")}, "diagnostics": {"vov": float("inf")}, "rays": 5})
    strict_files(tmp_path)
    back = PointStore(tmp_path / "pts", {"x": 1}, resume=True).get(0)
    assert back["values"]["pst"] == 0.0 and math.isnan(back["values"]["rel"]) and back["diagnostics"]["vov"] == math.inf


def test_old_checkpoint_with_nan_still_reads(tmp_path):
    """Backward compatibility: a point file written before strict JSON (NaN literal) still resumes."""
    from straylight.checkpoints import PointStore, point_checksum

    store = PointStore(tmp_path / "pts", {"x": 1})
    values = {"values": {"rel": float("nan")}}
    doc = {"index": 0, "run_sha256": store.digest, "values": values, "sha256": point_checksum(store.digest, 0, values)}
    (tmp_path / "pts" / "point_000000.json").write_text(json.dumps(doc))
    assert math.isnan(PointStore(tmp_path / "pts", {"x": 1}, resume=True).get(0)["values"]["rel"])


def test_every_command_writes_strict_json(scene, tmp_path, monkeypatch):
    """trace, pst, paths, critical, material eval/show, geometry check: all their JSON files strict.
    The scene has a detector no light reaches ('dark'), whose relative errors are not finite."""
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "out"
    runs = [
        ["trace", str(scene), "--rays", "1000", "--json", str(out / "trace.json")],
        ["pst", str(scene), "--angles-deg", "0", "60", "--rays", "1000", "--out", str(out / "pst")],
        ["pst", str(scene), "--detector", "dark", "--angles-deg", "0", "--rays", "500", "--out", str(out / "pst_dark")],
        ["paths", str(scene), "--angle-deg", "10", "--rays", "1000", "--out", str(out / "paths")],
        ["critical", str(scene), "--angle-deg", "10", "--rays", "1000", "--out", str(out / "critical")],
        ["material", "eval", "z302_sample_a", "--theta-i-deg", "10", "--theta-r-deg", "0", "30",
         "--polarization", "u", "--json", str(out / "eval.json")],
        ["material", "show", "z302_sample_a", "--theta-i-deg", "0", "89.9", "--json", str(out / "show.json")],
        ["geometry", "check", str(scene), "--json", str(out / "check.json")],
    ]
    for argv in runs:
        assert main(argv) in (0, 1), argv
    files = strict_files(out)
    names = {p.name for p in files}
    assert {"trace.json", "pst.json", "paths.json", "eval.json", "show.json", "check.json"} <= names, names
