"""Every example in examples/ runs ("examples/ executed by a test"), with few rays.

Each example is run the way its own documentation says (the command in the example's docstring or
header, through the ``straylight`` CLI's ``main``), scaled down: ``--rays`` and the sweep values are
made small here, the users' defaults stay in the files. A new example without a run below fails
:func:`test_every_example_has_a_run`.
"""
from __future__ import annotations

import ast
import json
import math
import shlex
from pathlib import Path

import pytest

from straylight.cli.main import main

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
FEW_RAYS = "300"


def _examples() -> set[str]:
    """examples/*.py and every folder of examples/ (a scene with its files)."""
    return {p.name for p in EXAMPLES.iterdir() if p.suffix == ".py" or (p.is_dir() and not p.name.startswith((".", "_")))}


def _docstring_command(path: Path) -> list[str]:
    """The ``straylight ...`` command of a module's docstring (continuation lines joined), without
    the program name."""
    doc = ast.get_docstring(ast.parse(path.read_text()))
    text = doc.replace("\\\n", " ")
    line = next(line.strip() for line in text.splitlines() if line.strip().startswith("straylight "))
    return shlex.split(line)[1:]


def _scaled(argv: list[str], out: Path, **replace) -> list[str]:
    """``argv`` with ``--out`` in ``out``, ``--rays`` few, and any ``--option VALUES...`` in ``replace``
    (key: the option without dashes, underscores for dashes) given the new values."""
    args, i = [], 0
    options = {"--out": [str(out)], "--rays": [FEW_RAYS], **{f"--{k.replace('_', '-')}": v for k, v in replace.items()}}
    while i < len(argv):
        a = argv[i]
        if a in options:
            args += [a, *options[a]]
            i += 1
            while i < len(argv) and not argv[i].startswith("--"):
                i += 1
        else:
            args.append(a)
            i += 1
    for a, v in options.items():  # options the documented command leaves to their defaults
        if a not in args:
            args += [a, *v]
    return args


RUNS = {"parametric_baffle.py", "own_instrument", "telescopes", "lens_with_barrel.py"}


def test_every_example_has_a_run():
    assert _examples() == RUNS, "add a run to tests/test_examples.py for every example"


def test_parametric_baffle_study_sweep(tmp_path, monkeypatch):
    """examples/parametric_baffle.py through its documented ``study --model`` sweep (two vane counts,
    few rays, PST at 0 and 20 deg): the report, the PST of the default design (its detector disk's
    area), and a PST per vane count and sweep angle."""
    monkeypatch.chdir(ROOT)  # the documented command's path is relative to the repository
    argv = _docstring_command(EXAMPLES / "parametric_baffle.py")
    assert argv[:3] == ["study", "--model", "examples/parametric_baffle.py:build"]
    out = tmp_path / "baffle_report"
    assert main(_scaled(argv, out, sweep_values=["3", "5"], angles_deg=["0", "20"])) == 0
    assert (out / "index.html").is_file()
    pst = json.loads((out / "pst.json").read_text())  # the design at build()'s defaults
    assert [p["off_axis_deg"] for p in pst["points"]] == [0.0, 20.0] and pst["points"][0]["pst"] > 0
    # the 30 mm detector sheet, meshed at the SCENE's 0.1 mm chord tolerance: an inscribed polygon short of
    # pi r^2 by at most the segments' area, 2/3 x sagitta x perimeter
    area, r_mm, chord_mm = pst["detector_area_mm2"], 30.0, 0.1
    assert math.pi * r_mm**2 - 2.0 / 3.0 * chord_mm * 2.0 * math.pi * r_mm <= area <= math.pi * r_mm**2
    sweep = json.loads((out / "sweep.json").read_text())
    assert sweep["parameter"] == "vane_count" and sweep["values"] == [3.0, 5.0]
    assert len(sweep["points"]) == 2 * len(sweep["off_axis_deg"])
    assert all(p["pst"] > 0 and p["pst_stderr"] > 0 for p in sweep["points"])


def test_own_instrument_scene_pst(tmp_path, monkeypatch):
    """examples/own_instrument/instrument.toml (a third-party STEP part placed three times, analytic
    wall and detector): the PST at 0 deg with few rays. Detector area pi 50^2 mm^2 (its exact disk);
    on axis light passes the three 76.2 mm bores and reaches the 50 mm disk."""
    monkeypatch.setenv("STRAYLIGHT_CACHE", "on")  # cached: tests/test_readme_own_instrument.py meshes it too
    monkeypatch.setenv("STRAYLIGHT_CACHE_DIR", str(tmp_path / "cache"))
    out = tmp_path / "pst"
    scene = EXAMPLES / "own_instrument" / "instrument.toml"
    assert main(["pst", str(scene), "--angles-deg", "0", "--rays", FEW_RAYS, "--seed", "1", "--out", str(out)]) == 0
    pst = json.loads((out / "pst.json").read_text())
    assert pst["detector"] == "detector"
    assert pst["detector_area_mm2"] == pytest.approx(math.pi * 50.0**2)
    assert pst["points"][0]["detector_w"] > 0


def test_telescopes_scenes_trace_to_their_image(tmp_path):
    """examples/telescopes/*.toml (two-mirror telescopes from published prescriptions, docs/baffles.md): each
    puts on-axis light on its image; the baffle design itself is tested in tests/straylight/test_design_baffles.py."""
    for scene in sorted((EXAMPLES / "telescopes").glob("*.toml")):
        out = tmp_path / scene.stem
        assert main(["pst", str(scene), "--angles-deg", "0", "--rays", FEW_RAYS, "--seed", "1", "--out", str(out)]) == 0
        pst = json.loads((out / "pst.json").read_text())
        assert pst["detector"] == "image" and pst["points"][0]["detector_w"] > 0, scene.name


def test_lens_with_barrel_builds_a_scene_that_traces(tmp_path, monkeypatch):
    """examples/lens_with_barrel.py: the double Gauss imported from its CODE V file plus a CadQuery STEP
    barrel; its scene.toml traces (few rays) and light reaches the image on axis."""
    import importlib.util

    monkeypatch.setenv("STRAYLIGHT_CACHE_DIR", str(tmp_path / "cache"))
    spec = importlib.util.spec_from_file_location("lens_with_barrel", EXAMPLES / "lens_with_barrel.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.main(str(tmp_path / "lwb"))
    scene = tmp_path / "lwb" / "scene.toml"
    assert scene.exists() and "barrel" in scene.read_text()
    out = tmp_path / "pst"
    assert main(["pst", str(scene), "--angles-deg", "0", "--rays", "2000", "--seed", "1", "--out", str(out)]) == 0
    assert json.loads((out / "pst.json").read_text())["points"][0]["detector_w"] > 0
