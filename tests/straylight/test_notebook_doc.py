"""docs/notebook.md runs as written, and its Python example gives the numbers of its `straylight` commands.

The ```python blocks of the page are run in order in one namespace (as a notebook would), in a
temporary folder; then each `straylight ...` line of its ```sh block is run through the command's
entry point, and the files those commands write are compared with the example's result objects:
the same seed must give the same numbers, bit for bit (one code path: straylight.api)."""
from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import pytest

DOC = Path(__file__).resolve().parents[2] / "docs" / "notebook.md"


def _blocks(lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", DOC.read_text(), re.S)


@pytest.fixture(scope="module")
def ran(tmp_path_factory):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pytest.importorskip("pandas")
    from straylight.cli.main import main

    work = tmp_path_factory.mktemp("notebook")
    ns: dict = {}
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(work)
        example = _blocks("python")[0]
        exec(compile(example, str(DOC), "exec"), ns)  # noqa: S102 - the documentation's own example
        plt.close("all")
        commands = [line for block in _blocks("sh") for line in block.splitlines() if line.startswith("straylight ")]
        for line in commands:
            assert main(shlex.split(line)[1:]) == 0, line
        # the reader snippet of the page runs on the files the commands wrote
        reader = _blocks("python")[1]
        exec(compile(reader, str(DOC), "exec"), ns)  # noqa: S102
    return work, ns, commands


def test_the_doc_names_the_three_commands(ran):
    _, _, commands = ran
    assert [c.split()[1] for c in commands] == ["pst", "paths", "critical"]


def test_pst_same_numbers_as_the_command(ran):
    work, ns, _ = ran
    doc = json.loads((work / "pst_out" / "pst.json").read_text())
    res = ns["pst"]
    assert [p["off_axis_deg"] for p in doc["points"]] == [0.0, 10.0, 20.0, 30.0]
    assert [p["pst"] for p in doc["points"]] == [float(x) for x in res.pst]
    assert [p["pst_stderr"] for p in doc["points"]] == [float(x) for x in res.pst_stderr]
    df = res.to_pandas()
    assert list(df["pst"]) == [float(x) for x in res.pst]
    assert list(df["flags"]) == [p["flags"] for p in doc["points"]]
    curve = ns["curve"]  # the page's reader, on the command's pst.csv
    assert list(curve.columns) == ["azimuth_deg", "off_axis_deg", "pst", "pst_stderr", "flags"]
    assert list(curve["pst"]) == [float(x) for x in res.pst]


def test_paths_same_numbers_as_the_command(ran):
    work, ns, _ = ran
    doc = json.loads((work / "paths_out" / "paths.json").read_text())
    rep = ns["paths"]
    assert doc["total_w"] == rep.total_w and doc["total_stderr_w"] == rep.total_stderr_w
    assert [(g["label"], g["power_w"]) for g in doc["groups"]] == [(r.label, r.power_w) for r in rep.rows[:len(doc["groups"])]]
    df = rep.to_pandas()
    assert list(df["path"][:3]) == [r.label for r in rep.rows[:3]]
    assert ns["absorbed_w"] == {k: v.power_w for k, v in rep.trace.absorbed.items()}
    assert (work / "tube_view.html").stat().st_size > 100_000


def test_critical_same_numbers_as_the_command(ran):
    work, ns, _ = ran
    doc = json.loads((work / "critical_out" / "critical.json").read_text())
    crit = ns["crit"]
    assert {p["part"]: (p["illuminated"], p["view_factor"], p["score"]) for p in doc["parts"]} == \
        {r.part: (r.illuminated, r.view_factor, r.score) for r in crit.rows}
    df = crit.to_pandas()
    assert set(df["part"]) == {r.part for r in crit.rows}
