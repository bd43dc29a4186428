"""Path report: groups partition the detector power; ancestry classes on scenes whose answer is known."""
import math

import numpy as np
import pytest

from materials import Lambertian
from straylight.analyses.builtin import tube_setup
from straylight.analyses.types import Setup
from straylight.analyses.paths_report import ANCESTRY, GROUP_BY, ancestry_of, path_report, paths_analysis, sequence_label


@pytest.fixture(scope="module")
def grey_tube_30deg():
    """Empty tube (no vanes) with rd = 0.5 walls, beam at 30 deg: past the 15.8 deg cut-off, so
    every detected watt was scattered at least once."""
    base = tube_setup(material=Lambertian(rd=0.0), vane_count=0)
    setup = Setup(base.scene, {"coating": Lambertian(rd=0.5)}, base.beam, base.entrance, "detector")
    return paths_analysis(setup, math.radians(30.0), n_rays=20_000, seed=2)


@pytest.mark.parametrize("group_by", GROUP_BY)
def test_group_fractions_sum_to_detector_total(grey_tube_30deg, group_by):
    """The engine tallies the detector total separately from the path records; the groups
    partition the records, so their powers must sum to that total (to round-off)."""
    report, res = grey_tube_30deg
    total = res.detectors["detector"].power_w
    assert total > 0  # sanity: light reaches the detector
    rep = path_report(res.paths, "detector", res.detectors["detector"], group_by=group_by)
    assert sum(r.power_w for r in rep.rows) == pytest.approx(total, rel=1e-9)
    assert sum(r.fraction for r in rep.rows) == pytest.approx(1.0, rel=1e-9)
    assert all(r.stderr_w >= 0 for r in rep.rows)


def test_ancestry_past_cutoff_is_all_scattered(grey_tube_30deg):
    report, res = grey_tube_30deg
    assert report.ancestry_w["direct"][0] == 0.0
    assert report.ancestry_w["specular_only"][0] == 0.0
    once, more = report.ancestry_w["scattered_once"][0], report.ancestry_w["scattered_more"][0]
    assert once > 0 and more > 0
    assert once + more == pytest.approx(report.total_w, rel=1e-9)
    # the filtered report keeps only its class, and its rows sum to that class's total
    only_more = path_report(res.paths, "detector", res.detectors["detector"], ancestry=["scattered_more"])
    assert {r.ancestry for r in only_more.rows} == {"scattered_more"}
    assert sum(r.power_w for r in only_more.rows) == pytest.approx(more, rel=1e-9)
    # a single-scatter path in this scene is source -> wall -> detector or via the end plate
    top_once = [r for r in report.rows if r.ancestry == "scattered_once"]
    assert top_once and all(r.label.count("->") == 2 for r in top_once)


def test_black_tube_on_axis_is_all_direct():
    """Black walls at 0 deg: only unscattered light is detected (49 % of the entrance power)."""
    setup = tube_setup(material=Lambertian(rd=0.0), vane_count=0)
    report, res = paths_analysis(setup, 0.0, n_rays=5_000, seed=1)
    assert report.total_w > 0
    assert report.ancestry_w["direct"][0] == pytest.approx(report.total_w, rel=1e-12)
    assert report.rows[0].label == "source -> detector"


def test_labels_and_classes():
    ev = (("wall", "scatter"), ("wall", "scatter"), ("vane_7", "specular"))
    assert sequence_label(ev, "detector") == "source -> wall x2 -> vane_7 (specular) -> detector"
    assert ancestry_of(()) == "direct"
    assert ancestry_of((("m", "specular"),)) == "specular_only"
    assert ancestry_of((("w", "scatter"), ("m", "specular"))) == "scattered_once"
    assert ancestry_of(ev) == "scattered_more"
    assert set(ANCESTRY) == {"direct", "specular_only", "scattered_once", "scattered_more", "diffracted"}
    bent = (("vane_7", "diffraction"), ("wall", "scatter"))
    assert ancestry_of(bent) == "diffracted"  # CONTRACTS §6.5
    assert sequence_label(bent, "detector") == "source -> diffracted at vane_7 -> wall -> detector"


def test_outputs(grey_tube_30deg, tmp_path):
    report, _ = grey_tube_30deg
    md = report.markdown(top=5)
    assert "| rank | path |" in md and "more groups" in md
    report.write_csv(tmp_path / "p.csv")
    report.write_json(tmp_path / "p.json")
    report.plot(tmp_path / "p.png")
    assert (tmp_path / "p.png").stat().st_size > 10_000
    assert len((tmp_path / "p.csv").read_text().splitlines()) == len(report.rows) + 1


def test_unknown_ancestry_is_a_clear_error(grey_tube_30deg):
    _, res = grey_tube_30deg
    with pytest.raises(ValueError, match="unknown ancestry"):
        path_report(res.paths, "detector", ancestry=["bounced"])
    np.testing.assert_equal(len(res.paths) > 0, True)
