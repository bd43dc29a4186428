"""``straylight study --builtin cassegrain`` runs from the command line and separates the
contributions. The path classes partition the focal plane's power, so they must add up
to the total (to round-off); on axis the nominal image dominates and the filter's two-bounce ghost
carries about R^2 of it (R = 4.3 % for n = 1.5195 at normal incidence: Fresnel)."""
import json

from straylight.analyses.telescope import CONTRIBUTIONS, classify
from straylight.cli.main import main


def test_classify_paths():
    spec = "specular"
    assert classify(()) == "direct"
    assert classify((("filter_top", spec), ("filter_bottom", spec))) == "direct"
    assert classify((("primary", spec), ("secondary", spec), ("filter_top", spec), ("filter_bottom", spec))) == "nominal"
    assert classify((("primary", spec), ("secondary", spec), ("filter_top", spec), ("filter_bottom", spec),
                     ("filter_top", spec), ("filter_bottom", spec))) == "ghost"
    assert classify((("primary", "scatter"), ("secondary", spec))) == "mirror scatter"
    assert classify((("vane_3", "scatter"), ("primary", spec))) == "vanes"
    assert classify((("tube", "scatter"), ("vane_1", "scatter"))) == "baffles and tube"


def test_cassegrain_study_cli(tmp_path):
    out = tmp_path / "study"
    rc = main(["study", "--builtin", "cassegrain", "--out", str(out), "--rays", "4000", "--seed", "1",
               "--angles-deg", "0", "2"])
    assert rc == 0
    res = json.loads((out / "results.json").read_text())
    assert (out / "index.html").exists() and (out / "pst.png").exists() and (out / "ghosts.md").exists()
    on, off = res["points"]
    for p in (on, off):
        parts = sum(p["contributions"][c]["pst"] for c in CONTRIBUTIONS)
        assert abs(parts - p["pst"]) <= 1e-9 * max(p["pst"], 1e-300)
    assert on["contributions"]["nominal"]["pst"] > 0.9 * on["pst"]
    assert on["pst_normalized"] == 1.0 and off["pst_normalized"] < 1e-2
    ghost = on["contributions"]["ghost"]["pst"]
    R = ((1.5195 - 1) / (1.5195 + 1)) ** 2
    assert ghost > 0 and abs(ghost / on["contributions"]["nominal"]["pst"] - R * R) < 5 * on["contributions"]["ghost"]["pst_stderr"] / on["contributions"]["nominal"]["pst"]


def test_paths_ghost_filter_on_the_cassegrain(tmp_path):
    """``straylight paths --builtin cassegrain --ghosts``: the ranked specular paths, nominal first."""
    rc = main(["paths", "--builtin", "cassegrain", "--angle-deg", "0", "--rays", "3000", "--seed", "2", "--ghosts",
               "--out", str(tmp_path)])
    assert rc == 0
    doc = json.loads((tmp_path / "ghosts.json").read_text())
    assert doc["rows"][0]["kind"] == "nominal"
    assert doc["rows"][0]["sequence"] == "source -> primary -> secondary -> filter_top -> filter_bottom -> focal_plane"
