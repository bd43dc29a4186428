"""The user guide's "Your own instrument" (docs/guide.md) stays true: its commands run (with few rays) on the real third-party part
it names, and its TOML excerpt is the example scene file's."""
import json
import math
import re
import shlex
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "own_instrument" / "instrument.toml"


def _section() -> str:
    text = (ROOT / "docs" / "guide.md").read_text()
    start = text.index("### Your own instrument\n")
    return text[start:text.index("\n### ", start + 1)]


def _blocks(lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", _section(), re.DOTALL)


def _commands() -> list[list[str]]:
    """The section's `straylight ...` command lines, except the one on a file the reader brings (scope.step)."""
    lines = [line for block in _blocks("bash") for line in block.splitlines() if line.startswith("straylight ")]
    return [shlex.split(line, comments=True)[1:] for line in lines if "scope." not in line]


def test_readme_toml_excerpt_is_taken_from_the_example_scene():
    example = EXAMPLE.read_text()
    excerpts = [b for b in _blocks("toml") if "rotate_deg" in b]
    assert excerpts
    for stanza in excerpts[0].strip().split("\n\n"):
        assert stanza.strip() in example, stanza


@pytest.fixture
def cached_tessellation(tmp_path, monkeypatch):
    monkeypatch.setenv("STRAYLIGHT_CACHE", "on")  # the STEP file is read by several commands: mesh it once
    monkeypatch.setenv("STRAYLIGHT_CACHE_DIR", str(tmp_path / "cache"))


def test_readme_commands_run_from_step_to_report(tmp_path, monkeypatch, cached_tessellation):
    from straylight.cli.main import main

    monkeypatch.chdir(ROOT)  # the README's paths are relative to the repository
    commands = _commands()
    assert [c[:2] for c in commands] == [["geometry", "scene"], ["geometry", "check"], ["pst", "plate.toml"],
                                         ["geometry", "check"], ["study", str(EXAMPLE.relative_to(ROOT))]]
    written = {}
    for argv in commands:
        args, i = [], 0
        while i < len(argv):
            a = argv[i]
            if a in ("-o", "--out"):  # outputs go to the test's folder
                written[argv[i + 1]] = str(tmp_path / argv[i + 1])
                args += [a, written[argv[i + 1]]]
                i += 2
            elif a == "--rays":  # few rays
                args += [a, "300"]
                i += 2
            else:
                args.append(written.get(a, a))
                i += 1
        if args[0] == "study":
            args += ["--angles-deg", "0", "20"]
        assert main(args) == 0, args
    pst = json.loads((tmp_path / "plate_pst" / "pst.json").read_text())
    assert pst["detector"] == "detector" and pst["detector_area_mm2"] == pytest.approx(math.pi * 50.0 ** 2)
    assert pst["points"][0]["detector_w"] > 0  # light reaches the disk through the plate's bore
    report = (tmp_path / "vanes_report" / "report.md").read_text()
    assert "Detector `detector` (exact disk, outer radius 50 mm" in report
    assert "Material `z302_sample_b` on 4 parts: vane_1, vane_2, vane_3, wall." in report
    assert "wall, vanes and end plate" not in report and "sweep.csv" not in report
    assert (tmp_path / "vanes_report" / "index.html").exists()
