"""``--model FILE.py:build`` sweeps over the user's own CadQuery code.

The model (written here) is an absorbing plate with a round hole of radius R at height h above a
detector disk of radius r_d, lit by a collimated beam. Nothing scatters, so the PST is geometry:
the hole's shadow (radius R, shifted by s = h tan a) overlaps the detector in a circle-circle lens
(Weisstein, "Circle-Circle Intersection", MathWorld), and PST = cos(a) * lens / A_det (the
detector irradiance is E_in cos a where lit). The sweep over R must give that within 4 sigma.
"""
import json
import math

import numpy as np
import pytest

from straylight.cli.main import main

H_MM, RD_MM, PLATE_MM = 20.0, 10.0, 0.02

MODEL = f'''
import cadquery as cq

def build(hole_radius_mm=5.0, plate_mm={PLATE_MM}):
    plate = (cq.Workplane("XY").workplane(offset={H_MM}).rect(40, 40).circle(hole_radius_mm)
             .extrude(plate_mm))
    detector = cq.Face.makeFromWires(cq.Wire.makeCircle({RD_MM}, cq.Vector(0, 0, 0), cq.Vector(0, 0, 1)))
    return {{"plate": plate, "detector": detector}}

SCENE = {{
    "parts": {{"detector": {{"role": "detector"}}, "plate": {{"role": "absorber"}}}},
    "source": [{{"type": "collimated_disk", "center_mm": [0.0, 0.0, 30.0], "normal": [0.0, 0.0, -1.0],
                 "direction": [0.0, 0.0, -1.0], "radius_mm": 18.0}}],
    "tolerance_mm": 0.005,
}}
'''


def lens_area(r1, r2, d):
    """Area of the intersection of two circles of radii r1, r2 whose centres are d apart."""
    if d >= r1 + r2:
        return 0.0
    if d <= abs(r1 - r2):
        return math.pi * min(r1, r2) ** 2
    a1 = r1 * r1 * math.acos((d * d + r1 * r1 - r2 * r2) / (2 * d * r1))
    a2 = r2 * r2 * math.acos((d * d + r2 * r2 - r1 * r1) / (2 * d * r2))
    return a1 + a2 - 0.5 * math.sqrt((-d + r1 + r2) * (d + r1 - r2) * (d - r1 + r2) * (d + r1 + r2))


@pytest.fixture()
def model(tmp_path):
    path = tmp_path / "aperture.py"
    path.write_text(MODEL)
    return f"{path}:build"


def test_model_sweep_matches_the_geometric_pst(model, tmp_path):
    from straylight.analyses.model import model_sweep

    angles = np.radians([0.0, 20.0])
    sweep = model_sweep(model, "hole_radius_mm", [5.0, 8.0], angles, tmp_path / "designs", n_rays=20_000,
                        seed=3)
    for i, radius in enumerate((5.0, 8.0)):
        scene = tmp_path / "designs" / f"hole_radius_mm={radius:g}" / "scene.toml"
        assert scene.is_file()
        for j, a in enumerate(angles):
            # the shadow of the hole's lower edge (the thin plate's upper edge cuts 0.02 tan a less)
            lens = lens_area(radius, RD_MM, H_MM * math.tan(a))
            det_area = math.pi * RD_MM**2  # the mesh is within 0.005 mm of the circle: < 0.1 % off
            expected = math.cos(a) * lens / det_area
            got, err = sweep.pst[i, j], sweep.pst_stderr[i, j]
            assert err >= 0  # the straight light is computed (direct_area): an error of round-off only
            assert abs(got - expected) < 4 * err + 2e-3 * expected, (radius, math.degrees(a), got, expected, err)
    assert sweep.pst[1, 1] < 0.95 * math.cos(angles[1]) * 0.64  # 8 mm at 20 deg: clipped by the detector edge


def test_study_with_model_writes_report_and_sweep(model, tmp_path):
    out = tmp_path / "report"
    assert main(["study", "--model", model, "--sweep-parameter", "hole_radius_mm", "--sweep-values", "4", "6",
                 "--rays", "1000", "--angles-deg", "0", "10", "--path-angle-deg", "10", "--out", str(out)]) == 0
    doc = json.loads((out / "results.json").read_text())
    assert doc["sweep"]["parameter"] == "hole_radius_mm" and doc["sweep"]["values"] == [4.0, 6.0]
    assert (out / "sweep.png").stat().st_size > 0 and (out / "model_scene" / "scene.toml").is_file()
    assert "aperture.py:build" in (out / "index.html").read_text()
    p0 = doc["pst"]["points"][0]["pst"]
    assert p0 == pytest.approx(25 / 100, rel=0.15)  # default R = 5 mm on a 10 mm detector, on axis


@pytest.mark.parametrize("text, argv_tail, message", [
    (MODEL, ["--sweep-parameter", "vane_count", "--sweep-values", "3"], "build() has no parameter 'vane_count'"),
    (MODEL.replace("SCENE = {", "NOT_SCENE = {"), [], "no scene settings"),
    (MODEL.replace('"plate": {"role": "absorber"}', '"plat": {"role": "absorber"}'), [],
     "names part(s) the model did not build: plat"),
    ("def build():\n    return 3\n", [], "must return a dict of named CadQuery parts"),
])
def test_bad_model_is_one_line(tmp_path, capsys, text, argv_tail, message):
    path = tmp_path / "bad.py"
    path.write_text(text)
    rc = main(["study", "--model", f"{path}:build", *argv_tail, "--rays", "100", "--out", str(tmp_path / "o")])
    errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("straylight: error")]
    assert rc == 2 and len(errors) == 1 and message in errors[0], errors


def test_assembly_parts_are_named_and_placed():
    import cadquery as cq

    from straylight.analyses.model import model_parts

    box = cq.Workplane("XY").box(2, 2, 2)
    assy = cq.Assembly(name="scope")
    assy.add(box, name="a", loc=cq.Location(cq.Vector(10, 0, 0)))
    sub = cq.Assembly(name="sub", loc=cq.Location(cq.Vector(0, 5, 0)))
    sub.add(box, name="b", loc=cq.Location(cq.Vector(0, 0, 3)))
    assy.add(sub)
    parts, scene = model_parts(assy, {"source": []}, "test")
    assert sorted(parts) == ["a", "b"]
    np.testing.assert_allclose(parts["a"].Center().toTuple(), (10, 0, 0), atol=1e-9)
    np.testing.assert_allclose(parts["b"].Center().toTuple(), (0, 5, 3), atol=1e-9)
