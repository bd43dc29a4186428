"""Hostile input: in a closed perfect-mirror cavity the thermal walk ends at its event cap. ``exchange``
booked what the paths still carried there as absorbed by the perfect mirror (4.3 % on main 13a6b5b,
where ``trace`` warned on the same scene). Now it is booked to no part, reported as ``truncated`` and
warned; a perfect mirror (emissivity 0, reflectance 1) absorbs exactly nothing."""
from __future__ import annotations

import json

import numpy as np
import pytest

import straylight.thermal.walk as walk_mod
from straylight import api
from straylight.run_checks import TruncationWarning

BOX = """
[material.perfect]
components = [{type = "specular", r = 1.0}]

[[part]]
name = "wall"
surface = {type = "cylinder", vertex_mm = [0.0, 0.0, 0.0], axis = [0.0, 0.0, 1.0], radius_mm = 30.0, length_mm = 100.0}
material = "perfect"

[[part]]
name = "bottom"
surface = {type = "plane", vertex_mm = [0.0, 0.0, 0.0], axis = [0.0, 0.0, 1.0], outer_radius_mm = 30.0}
material = "perfect"

[[part]]
name = "top"
surface = {type = "plane", vertex_mm = [0.0, 0.0, 100.0], axis = [0.0, 0.0, -1.0], outer_radius_mm = 30.0}
material = "perfect"

[[part]]
name = "det"
role = "detector"
temperature_k = 300.0
surface = {type = "plane", vertex_mm = [0.0, 0.0, 50.0], axis = [0.0, 0.0, 1.0], outer_radius_mm = 0.5}
"""


@pytest.fixture
def box(tmp_path, monkeypatch):
    monkeypatch.setattr(walk_mod, "MAX_EVENTS", 40)  # the cap, reached fast (100 000 on a real run)
    path = tmp_path / "box.toml"
    path.write_text(BOX)
    return path


def test_event_cap_is_not_absorbed_by_a_perfect_mirror(box, tmp_path):
    with pytest.warns(TruncationWarning, match=r"event cap \(40 events: a closed mirror cavity\) stopped .* 'det'"):
        res = api.exchange(box, (8.0, 12.0), rays=400, seed=1)
    det = res.names.index("det")
    mirrors = [res.names.index(n) for n in ("wall", "bottom", "top")]
    assert np.all(res.d[det, mirrors] == 0.0)  # main: the cut power booked to the mirrors
    assert res.truncated[det] > 0.5  # a 0.5 mm detector in a closed box: most paths run to the cap
    np.testing.assert_allclose(res.d[det].sum() + res.escaped[det] + res.truncated[det], 1.0, rtol=1e-12)
    res.write(tmp_path)
    assert json.loads((tmp_path / "exchange_details.json").read_text())["truncated"][det] == res.truncated[det]


def test_thermal_reports_the_event_cap(box, tmp_path, capsys):
    """``thermal`` (reverse rays from the detector) dropped what its paths carried at the cap without a word."""
    from straylight.cli.main import main

    assert main(["thermal", str(box), "--band-um", "8", "12", "--rays", "400", "--out", str(tmp_path / "t")]) == 0
    err = capsys.readouterr().err
    assert err.count("warning: the thermal walk's event cap (40 events) stopped paths") == 1  # once, not per chunk
