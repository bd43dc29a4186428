"""Imported two-mirror telescopes: PST vs angle with the central obscuration and the primary's hole as the
lens file has them (docs/optics.md).

Ritchey-Chretien (ray-optics' rc_f16.seq), on axis, independent reference: the collimated beam that
reaches the image is the annulus between the secondary's outline (its black back obscures) and the
primary's clear aperture, reflected once by each aluminium mirror, so

    PST(0) = pi (r_primary^2 - r_secondary^2) R^2 / A_detector,

with R = ((n - 1)^2 + k^2) / ((n + 1)^2 + k^2) the normal-incidence reflectance of the aluminium n, k the
scene gives (Born & Wolf §14.2); the mirrors see the beam within ~11 deg of normal, where R changes by
< 0.5 %. Beyond the field the PST falls by orders of magnitude.

Maksutov-Cassegrain (questar35.seq): the light reaches the image only through the primary's hole: with
the hole closed the on-axis PST is 0.
"""
import json
import math
import tomllib
from pathlib import Path

import pytest

from straylight.cli.main import main

LENSES = Path(__file__).resolve().parent / "data" / "lenses" / "ray-optics"


def _pst(scene, out, angles, rays=20000):
    assert main(["pst", str(scene / "scene.toml"), "--angles-deg", *[str(a) for a in angles], "--rays", str(rays), "--seed", "3",
                 "--out", str(out)]) == 0
    return json.loads((out / "pst.json").read_text())["points"]


def _import(name, out):
    assert main(["optics", "import", str(LENSES / name), "--out", str(out)]) == 0
    return tomllib.loads((out / "scene.toml").read_text())


def test_ritchey_chretien_on_axis_pst_is_the_obscured_annulus_times_r_squared(tmp_path):
    doc = _import("rc_f16.seq", tmp_path / "rc")
    parts = {p["name"]: p for p in doc["part"]}
    primary, secondary, image = parts["s1"]["surface"], parts["s2"]["surface"], parts["image"]["surface"]
    assert primary["inner_radius_mm"] > 0  # the primary's hole
    n, k = doc["material"]["aluminium_mirror"]["components"][0]["n"]
    R = ((n - 1) ** 2 + k * k) / ((n + 1) ** 2 + k * k)
    expected = (primary["outer_radius_mm"] ** 2 - secondary["outer_radius_mm"] ** 2) * R * R / image["outer_radius_mm"] ** 2
    # the source starts in front of the whole secondary (its convex face reaches ~90 mm past its vertex)
    assert doc["source"][0]["center_mm"][2] < secondary["vertex_mm"][2] - 80
    p0, p_edge, p_far = _pst(tmp_path / "rc", tmp_path / "pst", [0, 1, 3])
    assert p0["pst"] == pytest.approx(expected, rel=0.01 + 4 * p0["pst_stderr"] / p0["pst"])
    assert p_edge["pst"] < 0.05 * p0["pst"] and p_far["pst"] < 0.05 * p0["pst"]


def test_maksutov_cassegrain_reaches_its_image_only_through_the_primary_hole(tmp_path):
    doc = _import("questar35.seq", tmp_path / "mk")
    holed = [p for p in doc["part"] if p.get("surface", {}).get("inner_radius_mm", 0) > 0 and p["name"].startswith("s")]
    assert holed, "the primary's hole (and the corrector's spot) are kept"
    (p0,) = _pst(tmp_path / "mk", tmp_path / "pst", [0], rays=10000)
    assert p0["pst"] > 1.0  # the telescope images the beam
    text = (tmp_path / "mk" / "scene.toml").read_text()
    primary = max(holed, key=lambda p: p["surface"]["vertex_mm"][2])  # the primary lies farthest along the light
    hole = f'inner_radius_mm = {primary["surface"]["inner_radius_mm"]!r}'
    assert hole in text
    closed = tmp_path / "closed"
    closed.mkdir()
    (closed / "scene.toml").write_text(text.replace(", " + hole, ""))
    (q0,) = _pst(closed, tmp_path / "pst_closed", [0], rays=10000)
    assert q0["pst"] == 0.0 or q0["pst"] < 1e-3 * p0["pst"]
    assert not math.isnan(p0["pst_stderr"])
