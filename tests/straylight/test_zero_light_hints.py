"""A zero result says what blocks the light: an opaque part named like an optic, a closed detector.

Scenes: the fusion-like scope (tests/data/cad/fusion_like_scope.step: a tube, a lens disk, a sensor) with the
lens left in the tube's black coating, then given glass; and a detector boxed in by a cap."""
from pathlib import Path

import numpy as np
import trimesh

STEP = Path(__file__).resolve().parents[1] / "data" / "cad" / "fusion_like_scope.step"
SOURCE = ('[[source]]\ntype = "collimated_disk"\ncenter_mm = [0.0, 0.0, 100.0]\nnormal = [0.0, 0.0, -1.0]\n'
          'direction = [0.0, 0.0, -1.0]\nradius_mm = 10.0\npower_w = 1.0\n')


def _scope(tmp_path, lens_material: str) -> Path:
    toml = tmp_path / "scope.toml"
    toml.write_text('[material.glass]\ncomponents = [{type = "dielectric", n = 1.5168}]\n'
                    f'[[part]]\nname = "scope"\nmesh = "{STEP}"\nsplit = "solids"\ntolerance_mm = 0.2\n'
                    'material = "z302_sample_b"\n[part.solids."ar0130 v4:1"]\nrole = "detector"\n'
                    f'[part.solids."lens v1"]\nmaterial = "{lens_material}"\n' + SOURCE)
    return toml


def test_an_opaque_lens_is_named_and_a_glass_one_is_not(tmp_path):
    from straylight.analyses.blockers import opaque_optics
    from straylight.analyses.scene_setup import scene_setup

    hints = opaque_optics(scene_setup(_scope(tmp_path, "z302_sample_b")))
    assert len(hints) == 1 and "part 'scope/lens v1' is named like an optic but is opaque" in hints[0]
    assert '[part.solids."lens v1"] material = "GLASS"' in hints[0] and "dielectric" in hints[0]
    assert opaque_optics(scene_setup(_scope(tmp_path, "glass"))) == []


def test_a_detector_boxed_in_is_reported_and_an_open_one_is_not(tmp_path):
    from straylight.analyses.blockers import closed_detector
    from straylight.analyses.scene_setup import scene_setup

    sensor = trimesh.creation.box(extents=(4.0, 4.0, 0.5))
    sensor.export(tmp_path / "sensor.stl")
    cap = trimesh.creation.box(extents=(10.0, 10.0, 10.0))  # a closed box around the sensor: outer shell ...
    inner = trimesh.creation.box(extents=(8.0, 8.0, 8.0))  # ... and its cavity, faces inward
    shell = trimesh.Trimesh(np.vstack([cap.vertices, inner.vertices]),
                            np.vstack([cap.faces, inner.faces[:, ::-1] + len(cap.vertices)]), process=False)
    shell.export(tmp_path / "cap.stl")
    base = ('[[part]]\nname = "sensor"\nmesh = "sensor.stl"\nrole = "detector"\n'
            '[[part]]\nname = "cap"\nmesh = "cap.stl"\nmaterial = "z302_sample_b"\n')
    (tmp_path / "closed.toml").write_text(base + SOURCE)
    hint = closed_detector(scene_setup(tmp_path / "closed.toml"))
    assert hint and "the detector 'sensor' is closed in" in hint and "(cap)" in hint
    (tmp_path / "open.toml").write_text('[[part]]\nname = "sensor"\nmesh = "sensor.stl"\nrole = "detector"\n' + SOURCE)
    assert closed_detector(scene_setup(tmp_path / "open.toml")) is None


def test_pst_prints_the_hint_when_nothing_arrives(tmp_path, capsys):
    """A tube whose bore a black "lens" fills: a beam inside the bore reaches the sensor by no path (PST exactly 0)."""
    from straylight.cli.main import main

    tube = trimesh.creation.annulus(r_min=20.0, r_max=22.0, height=80.0)
    tube.apply_translation((0.0, 0.0, 40.0))
    lens = trimesh.creation.cylinder(radius=20.0, height=4.0)
    lens.apply_translation((0.0, 0.0, 42.0))
    sensor = trimesh.creation.box(extents=(4.0, 4.0, 0.5))
    sensor.apply_translation((0.0, 0.0, 2.0))
    for name, mesh in (("tube", tube), ("front_lens", lens), ("sensor", sensor)):
        mesh.export(tmp_path / f"{name}.stl")
    toml = tmp_path / "scope.toml"
    toml.write_text('[[part]]\nname = "tube"\nmesh = "tube.stl"\nmaterial = "z302_sample_b"\n'
                    '[[part]]\nname = "front_lens"\nmesh = "front_lens.stl"\nmaterial = "z302_sample_b"\n'
                    '[[part]]\nname = "sensor"\nmesh = "sensor.stl"\nrole = "detector"\n' + SOURCE)
    code = main(["pst", str(toml), "--angles-deg", "0", "--rays", "2000", "--out", str(tmp_path / "out")])
    out = capsys.readouterr().out
    assert code == 0
    assert "no light reached the detector at any angle" in out and "part 'front_lens' is named like an optic" in out, out
    assert "the detector 'sensor' is closed in" in out  # every line of sight ends on the tube or the black lens
