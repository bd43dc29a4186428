"""The study runs end to end on a tiny ray count and writes a report a person can open."""
import json
from pathlib import Path

import pytest

from straylight.analyses.report import StudyConfig, run_study


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    out = tmp_path_factory.mktemp("report")
    cfg = StudyConfig(rays=2000, seed=1, angles_deg=(0.0, 10.0, 20.0), sweep_values=(0, 7), sweep_angles_deg=(20.0,))
    return run_study(out, cfg)


def test_study_writes_index_and_pngs(study):
    out = study.out_dir
    html = (out / "index.html").read_text()
    for name in ("pst.png", "paths.png", "critical.png", "sweep.png", "view_rays.png", "view_absorbed.png",
                 "detector_map.png"):
        assert (out / name).stat().st_size > 5_000, name
        assert f'src="{name}"' in html, name
    assert "<table>" in html and "Findings" in html
    assert (out / "report.md").exists()


def test_study_results_are_consistent(study):
    doc = json.loads((study.out_dir / "results.json").read_text())
    points = doc["pst"]["points"]
    assert [p["off_axis_deg"] for p in points] == [0.0, 10.0, 20.0]
    # on axis, 49 % of the entrance power reaches the detector directly (BENCHMARK.md direct(0) = 0.49);
    # with 2000 rays the binomial sigma is 0.011; 4 sigma
    assert abs(points[0]["entrance_ratio"] - 0.49) < 4 * 0.0112
    assert points[2]["pst"] < points[1]["pst"] < points[0]["pst"]
    ledger = doc["energy_ledger_at_path_angle"]
    total = ledger["detected_w"] + ledger["absorbed_w"] + ledger["escaped_w"]
    assert total == pytest.approx(ledger["emitted_w"], rel=1e-9)
    assert set(doc["sweep"]["values"]) == {0.0, 7.0}
    assert doc["paths"]["total_w"] > 0


def test_report_tables_as_csv(study):
    """Each table of index.html is also table_<name>.csv, with the numbers of results.json."""
    import csv

    report = study.out_dir
    page = (report / "index.html").read_text()
    doc = json.loads((report / "results.json").read_text())
    for name in ("pst", "paths", "ancestry", "critical", "sweep"):
        assert f'href="table_{name}.csv"' in page, name
    with open(report / "table_pst.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [float(r["off_axis_deg"]) for r in rows] == [p["off_axis_deg"] for p in doc["pst"]["points"]]
    assert [float(r["pst"]) for r in rows] == [p["pst"] for p in doc["pst"]["points"]]
    assert [r["flags"] for r in rows] == [p["flags"] for p in doc["pst"]["points"]]
    with open(report / "table_paths.csv", newline="") as fh:
        paths = list(csv.DictReader(fh))
    assert [r["path"] for r in paths][:5] == [g["label"] for g in doc["paths"]["groups"]][:5]
    assert sum(float(r["fraction"]) for r in paths) == pytest.approx(1.0, rel=1e-9)
    with open(report / "table_critical.csv", newline="") as fh:
        parts = {r["part"]: float(r["view_factor"]) for r in csv.DictReader(fh)}
    assert parts == {p["part"]: p["view_factor"] for p in doc["critical"]["parts"]}
    with open(report / "table_sweep.csv", newline="") as fh:
        sweep = list(csv.DictReader(fh))
    assert [float(r["vane_count"]) for r in sweep] == doc["sweep"]["values"]
    assert [float(r["pst_at_20_deg"]) for r in sweep] == [p["pst"] for p in doc["sweep"]["points"]
                                                          if p["off_axis_deg"] == 20.0]


def test_study_of_a_scene_where_nothing_absorbs(tmp_path):
    """A bare detector disk in the beam: no part absorbs, and the study still writes its report (CONTRACTS 4.5:
    index.html and results.json for any scene); the absorbed-power view was refused without an absorbed part."""
    from straylight.cli.main import main

    scene = tmp_path / "bare.toml"
    scene.write_text('[[part]]\nname = "det"\nsurface = {type = "plane", vertex_mm = [0.0, 0.0, 0.0], '
                     'axis = [0.0, 0.0, 1.0], outer_radius_mm = 5.0}\nrole = "detector"\n\n[[source]]\n'
                     'type = "collimated_disk"\ncenter_mm = [0.0, 0.0, 100.0]\nnormal = [0.0, 0.0, -1.0]\n'
                     'direction = [0.0, 0.0, -1.0]\nradius_mm = 50.0\npower_w = 2.0\n')
    assert main(["study", str(scene), "--out", str(tmp_path / "r")]) == 0
    assert (tmp_path / "r" / "index.html").exists() and (tmp_path / "r" / "view_absorbed.png").exists()
    assert json.loads((tmp_path / "r" / "results.json").read_text())
    assert json.loads((tmp_path / "r" / "results.json").read_text())["ghosts"] is None  # no lens: no ghost step
    assert not (tmp_path / "r" / "ghosts.csv").exists() and "Ghosts" not in (tmp_path / "r" / "index.html").read_text()


def test_study_of_an_imported_lens_has_its_ghost_table(tmp_path):
    """A study of a lens file's scene (the Cooke triplet through `optics import`) carries the ghost table on axis,
    the `ghosts` command's files and numbers (same seed: the same table), and a section of the report."""
    from straylight.analyses.ghost_trace import ghosts
    from straylight.analyses.grid import point_seed
    from straylight.cli.main import main

    lens = Path(__file__).resolve().parents[1] / "data" / "lenses" / "optiland" / "cooke_triplet.seq"
    assert main(["optics", "import", str(lens), "--out", str(tmp_path / "lens")]) == 0
    scene = tmp_path / "lens" / "scene.toml"
    assert main(["study", str(scene), "--rays", "2000", "--angles-deg", "0", "10", "--seed", "4",
                 "--out", str(tmp_path / "r")]) == 0
    doc = json.loads((tmp_path / "r" / "results.json").read_text())["ghosts"]
    assert len(doc["ghosts"]) == 15 and doc["order"] == 2 and doc["field_deg"] == 0.0
    alone = ghosts(scene, seed=point_seed(4, 8)).to_json_dict()
    assert [g["power_w"] for g in doc["ghosts"]] == [g["power_w"] for g in alone["ghosts"]]
    for name in ("ghosts.csv", "ghosts.json", "ghosts.md", "ghosts.png"):
        assert (tmp_path / "r" / name).stat().st_size > 0
    page = (tmp_path / "r" / "index.html").read_text()
    first = " &gt; ".join(doc["ghosts"][0]["surfaces"])
    assert "Ghosts (order 2, on axis)" in page and first in page and "5 more in" in page
    assert "## Ghosts" in (tmp_path / "r" / "report.md").read_text()


def test_a_ghost_table_the_analysis_refuses_is_said_in_the_report():
    from straylight.analyses.ghost_study import markdown_lines, report_section

    doc = {"skipped": "the nominal path crosses no transmitting interface: no ghost to list"}
    assert "No ghost table: the nominal path crosses no transmitting interface" in report_section(doc)
    assert markdown_lines(doc)[0] == "## Ghosts" and report_section(None) == "" and markdown_lines(None) == []
