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


def _blocks() -> list[tuple[str, str]]:
    """(language, code) of every ```python and ```sh block, in the page's order."""
    return re.findall(r"```(python|sh)\n(.*?)```", DOC.read_text(), re.DOTALL)


@pytest.fixture(scope="module")
def ran(tmp_path_factory):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pytest.importorskip("pandas")
    from straylight.cli.main import main

    work = tmp_path_factory.mktemp("notebook")
    ns: dict = {}
    commands = []
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(work)
        for lang, code in _blocks():  # as a reader would: each block in turn, in one namespace
            if lang == "python":
                exec(compile(code, str(DOC), "exec"), ns)  # noqa: S102 - the documentation's own example
                plt.close("all")
                continue
            for line in code.splitlines():
                if line.startswith("straylight "):
                    assert main(shlex.split(line)[1:]) == 0, line
                    commands.append(line)
    return work, ns, commands


def test_the_doc_names_the_commands(ran):
    _, _, commands = ran
    assert [c.split()[1] for c in commands] == ["pst", "paths", "critical", "thermal", "exchange"]


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
    # the command's --view3d page shows the same ranked paths as the notebook's
    page = (work / "paths_out" / "view3d.html").read_text()
    page = page.replace("\\u003c", "<").replace("\\u003e", ">").replace("\\u0026", "&")  # the page's JSON escapes
    assert all(r.label in page for r in rep.rows[:5])


def test_critical_same_numbers_as_the_command(ran):
    work, ns, _ = ran
    doc = json.loads((work / "critical_out" / "critical.json").read_text())
    crit = ns["crit"]
    assert {p["part"]: (p["illuminated"], p["view_factor"], p["score"]) for p in doc["parts"]} == \
        {r.part: (r.illuminated, r.view_factor, r.score) for r in crit.rows}
    df = crit.to_pandas()
    assert set(df["part"]) == {r.part for r in crit.rows}


def test_thermal_same_numbers_as_the_command(ran):
    work, ns, _ = ran
    doc = json.loads((work / "thermal_out" / "thermal.json").read_text())
    assert doc == ns["th"].to_json_dict()
    df = ns["th"].to_pandas()
    assert set(df["part"]) == {"baffle", "focal_plane"}
    assert df["power_w"].sum() == pytest.approx(doc["detectors"]["focal_plane"]["power_w"], rel=1e-12)
    ex = json.loads((work / "exchange_out" / "exchange.json").read_text())
    assert ex == ns["ex"].to_json_dict()
    d = ns["ex"].to_pandas()
    assert list(d.columns) == ["baffle", "focal_plane", "escaped"] or list(d.columns) == ["focal_plane", "baffle", "escaped"]
    # each row of D plus the escaped fraction is 1 (CONTRACTS §7.2)
    assert list(d.sum(axis=1)) == pytest.approx([1.0, 1.0], abs=1e-9)
