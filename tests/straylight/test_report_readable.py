"""The study report as a newcomer reads it: on a scene file no "unscattered (geometric)" caption nor an
all-"-" column; Method bullets rendered (no "- " nor backticks inside <li>); numbers that never wrap at their
minus sign; the PST plot with a panel giving the error bars' size; the static 3-D picture's legend beside the
scene, not over it."""
import re
from pathlib import Path

import numpy as np
import pytest

GOLDEN = Path(__file__).resolve().parents[1] / "data" / "engine_golden"


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    from straylight.analyses.report import StudyConfig, run_study

    out = tmp_path_factory.mktemp("report")
    run_study(out, StudyConfig(rays=500, seed=2, angles_deg=(0.0, 20.0), scene=str(GOLDEN / "tube.toml"), sweep=False))
    return out


def test_html_says_only_what_is_drawn_and_renders_the_method(report):
    page = (report / "index.html").read_text()
    assert "unscattered (geometric)" not in page  # a scene file: no geometric curve, no such column
    assert "1-sigma error bars (their size in % in the lower panel)" in page
    method = page[page.index("<h2>Method</h2>"):]
    items = re.findall(r"<li>(.*?)</li>", method)
    assert items and not any(i.startswith("- ") or "`" in i for i in items)
    assert "<code>detector</code>" in method
    assert "white-space: nowrap" in page and "shared/" not in page and "CONTRACTS" not in page


def test_no_table_column_is_all_dashes(report):
    from straylight.analyses.report import _without_empty_columns

    header, rows = _without_empty_columns(("a", "b", "c"), [("1", "-", "x"), ("2", "-", "-")])
    assert header == ("a", "c") and rows == [("1", "x"), ("2", "-")]
    page = (report / "index.html").read_text()
    for table in re.findall(r"<table>(.*?)</table>", page, re.S):
        rows = [re.findall(r"<td>(.*?)</td>", r) for r in re.findall(r"<tr>(.*?)</tr>", table)]
        rows = [r for r in rows if r]
        for k in range(len(rows[0]) if rows else 0):
            assert any(r[k] != "-" for r in rows), table[:200]


def test_pst_plot_has_the_error_panel(report):
    from PIL import Image

    w, h = Image.open(report / "pst.png").size
    assert h / w > 0.75  # two panels (7.5 x 6 in), not the single 7.5 x 4.8


def test_static_view_legend_leaves_the_scene_alone(report):
    """The parts and rays lie left of the legend's strip (the right 20 %): the picture's right strip below the
    legend's rows is blank (white)."""
    from PIL import Image

    img = np.asarray(Image.open(report / "view_rays.png").convert("RGB"), dtype=int)
    h, w, _ = img.shape
    strip = img[int(0.55 * h):int(0.95 * h), int(0.82 * w):]
    assert np.mean(np.all(strip > 235, axis=2)) > 0.98
