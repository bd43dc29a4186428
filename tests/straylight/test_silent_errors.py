"""Numbers that used to be silently wrong, and errors that used to say nothing useful: power
cut by ``max_events`` above 1 % is a warning; a source so far away that
Embree's float32 rounds its ray origins is a warning or a refusal (1e17 mm used to lose every ray);
a source radius of 1e-300 ("float division by zero"), a NaN vertex in a detector STL
("Eigenvalues did not converge") are one-line errors naming the entry; ``geometry check`` exits 1
when solids overlap."""
from __future__ import annotations

import re
import struct
import warnings
from pathlib import Path

import numpy as np
import pytest

from straylight.cli.main import main
from straylight.run_checks import PrecisionWarning, TruncationWarning, check_origin_precision
from straylight.sources import source_from_dict

GOLDEN = Path(__file__).resolve().parents[1] / "data" / "engine_golden"
BEAM = (0.0, 0.3420201433256687, -0.9396926207859084)  # the golden tube's beam direction


def _tube_scene(tmp_path, source_center=(0.0, 0.0, 320.0), radius_mm=30.0, detector_mesh=None):
    """The golden tube scene with its beam's disk moved along the beam (the same rays cross the tube)."""
    text = (GOLDEN / "tube.toml").read_text()
    text = re.sub(r'mesh = "([^"]+)"', lambda m: f'mesh = "{detector_mesh}"' if detector_mesh and
                  m.group(1) == "detector.stl" else f'mesh = "{GOLDEN / m.group(1)}"', text)
    text = text.replace("center_mm = [0.0, 0.0, 320.0]", f"center_mm = [{', '.join(map(repr, source_center))}]")
    text = text.replace("radius_mm = 30.0", f"radius_mm = {radius_mm!r}")
    path = tmp_path / "scene.toml"
    path.write_text(text)
    return path


def _along_beam(z):
    t = (z - 320.0) / -BEAM[2]
    return (-t * BEAM[0], -t * BEAM[1], float(z))


def test_truncated_power_above_one_percent_is_a_console_warning(tmp_path, capsys):
    scene = _tube_scene(tmp_path)
    assert main(["trace", str(scene), "--rays", "2000", "--max-events", "1", "--json", str(tmp_path / "o.json")]) == 0
    import json

    doc = json.loads((tmp_path / "o.json").read_text())
    share = doc["ledger"]["truncated_w"] / doc["emitted_w"]
    assert share > 0.01  # rd = 0.05 walls: ~5 % of the beam survives its first event and is cut there
    lines = [line for line in capsys.readouterr().err.splitlines() if "warning" in line]
    assert lines == [f"straylight: warning: max_events = 1 stopped {share:.1%} of the emitted power "
                     f"({doc['ledger']['truncated_w']:.3g} W, counted as absorbed): raise --max-events "
                     f"(PhysicsOptions.max_events)"]


def test_default_max_events_is_silent(tmp_path):
    from straylight.scene import load_scene
    from straylight.trace import trace

    rs = load_scene(_tube_scene(tmp_path))
    with warnings.catch_warnings():
        warnings.simplefilter("error", TruncationWarning)
        res = trace(rs.scene, rs.sources, 2000, 1, materials=rs.materials)
    assert res.ledger["truncated_w"].power_w < 0.01 * res.emitted_w


@pytest.mark.parametrize("z_mm, expect", [(320.0, None), (1e6, "warn"), (1e8, "refuse"), (1e17, "refuse")])
def test_far_source_float32_rounding_warns_or_refuses(z_mm, expect):
    """Rounding of a float32 origin at distance D is up to D 2^-24: 1e6 mm -> 0.06 mm (1.8e-4 of
    the 334 mm tube: warned); 1e8 mm -> 6 mm (1.8 %: refused; the absorbed power moved from 0.989 to
    0.998 there); 1e17 mm -> 6e9 mm (every ray escaped)."""
    src = source_from_dict({"type": "collimated_disk", "center_mm": list(_along_beam(z_mm)), "normal": [0, 0, -1],
                            "direction": list(BEAM), "radius_mm": 30.0, "power_w": 1.0}, where="t")
    bounds = (np.array([-60.0, -60.0, 0.0]), np.array([60.0, 60.0, 300.0]))  # 334 mm diagonal, as the tube
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if expect == "refuse":
            with pytest.raises(ValueError, match="rays would miss"):
                check_origin_precision([src], bounds)
        else:
            check_origin_precision([src], bounds)
    kinds = [w.category for w in caught]
    assert kinds == ([PrecisionWarning] if expect == "warn" else [])


def test_far_source_refused_by_the_command(tmp_path, capsys):
    scene = _tube_scene(tmp_path, source_center=_along_beam(1e17))
    assert main(["trace", str(scene), "--rays", "1000", "--json", str(tmp_path / "o.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "float32 rounds ray origins" in err[0] and not (tmp_path / "o.json").exists()


def test_tiny_source_radius_is_one_line_naming_the_source(tmp_path, capsys):
    scene = _tube_scene(tmp_path, radius_mm=1e-300)
    assert main(["trace", str(scene), "--rays", "1000", "--json", str(tmp_path / "o.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "[[source]] 1" in err[0] and "radius_mm 1e-300" in err[0]
    assert "division by zero" not in err[0]


def test_nan_vertex_in_detector_stl_is_one_line_naming_the_file(tmp_path, capsys):
    data = bytearray((GOLDEN / "detector.stl").read_bytes())
    data[84 + 12:84 + 16] = struct.pack("<f", float("nan"))  # binary STL: first vertex of the first triangle
    bad = tmp_path / "detector_nan.stl"
    bad.write_bytes(bytes(data))
    scene = _tube_scene(tmp_path, detector_mesh=bad)
    assert main(["pst", str(scene), "--angles-deg", "0", "--rays", "1000", "--out", str(tmp_path / "p")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(bad) in err[0] and "NaN or infinite" in err[0]
    assert "Eigenvalues" not in err[0]


def test_geometry_check_exits_1_when_solids_overlap(tmp_path, capsys):
    import trimesh

    for name, shift in (("a", 0.0), ("b", 5.0)):  # two 10 mm cubes overlapping by 5 x 10 x 10 = 500 mm^3
        box = trimesh.creation.box(extents=(10.0, 10.0, 10.0))
        box.apply_translation((shift, 0.0, 0.0))
        box.export(tmp_path / f"{name}.stl")
    scene = tmp_path / "scene.toml"
    scene.write_text('[[part]]\nname = "a"\nmesh = "a.stl"\nrole = "absorber"\n'
                     '[[part]]\nname = "b"\nmesh = "b.stl"\nrole = "absorber"\n')
    assert main(["geometry", "check", str(scene)]) == 1
    captured = capsys.readouterr()
    assert "overlap a / b: 500 mm^3, depth 5 mm" in captured.out
    assert captured.err.strip().splitlines() == [
        "straylight: geometry check: 1 overlap(s) change the trace (first: a / b, 500 mm^3, depth 5 mm: deeper than "
        "the chord tolerance 0.05 mm: changes the trace); move or trim the parts"]
