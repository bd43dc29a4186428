"""Tables for other programs (straylight.analyses.tables): the thermal budget's rows and the CSV writer."""
import csv
import math

import pytest

from straylight.analyses.tables import write_csv_table
from straylight.thermal.tables import THERMAL_TABLE, thermal_rows

# CONTRACTS §7.1's example document
DOC = {"band_um": [8.0, 12.0], "rays": 2000000, "seed": 1,
       "detectors": {"focal_plane": {"power_w": 0.0254, "stderr_w": 1.2e-05, "irradiance_w_m2": 90.1,
                                     "by_part": {"tube": {"power_w": 0.0251, "stderr_w": 1.2e-05},
                                                 "focal_plane": {"power_w": 0.0003, "stderr_w": 2e-07}}}}}


def test_thermal_rows_largest_first_with_shares():
    rows = thermal_rows(DOC)
    assert [(r["detector"], r["part"]) for r in rows] == [("focal_plane", "tube"), ("focal_plane", "focal_plane")]
    assert rows[0]["fraction"] == pytest.approx(0.0251 / 0.0254)
    assert rows[1]["power_w"] == 0.0003 and rows[1]["irradiance_w_m2"] == 90.1


def test_csv_writes_missing_values_as_empty_cells(tmp_path):
    path = write_csv_table(tmp_path / "t.csv", THERMAL_TABLE[:4],
                           [{"detector": "d", "part": "p", "power_w": math.nan, "stderr_w": None}])
    with open(path, newline="") as fh:
        assert list(csv.reader(fh)) == [list(THERMAL_TABLE[:4]), ["d", "p", "", ""]]


def test_a_notebook_shows_a_result_as_its_table():
    pytest.importorskip("pandas")
    from straylight.analyses.paths_report import PathReport, PathRow

    rows = [PathRow(1, "source -> vane_6 -> detector", "scattered_once", 3e-6, 1e-7, 0.75, 0.02, 40),
            PathRow(2, "source -> wall -> detector", "scattered_once", 1e-6, 1e-7, 0.25, 0.02, 12)]
    rep = PathReport(rows, 4e-6, 1.5e-7, "detector", 1000, "sequence", ())
    html = rep._repr_html_()
    assert html.startswith("<table") and "source -&gt; vane_6 -&gt; detector" in html and "0.75" in html
    assert list(rep.to_pandas()["rank"]) == [1, 2]
