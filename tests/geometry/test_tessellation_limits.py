"""Refinement that converges or says why: a face whose chord error cannot fall stops refining with a warning
and stays within the triangle budget; a tolerance that would need more triangles than the budget is
meshed at the finest deflection the budget allows, up front."""
from pathlib import Path

import pytest

from geometry.tessellate import TessellationWarning, tessellate

FEATURETYPE = Path(__file__).resolve().parents[1] / "data" / "cad" / "third_party" / "featuretype.STEP"


def test_face_whose_error_cannot_fall_stops_with_a_warning_within_budget():
    """featuretype.STEP (SolidWorks 2013, trimesh's models, MIT): on its B-spline face 79 OpenCascade keeps a
    long triangle edge whose midpoint is 0.13 mm off the surface (checked by projection) at every deflection
    asked; refinement must stop, name the face, and keep within the budget."""
    from geometry.cad import read_cad

    (solid,) = read_cad(FEATURETYPE)
    budget = 60_000
    with pytest.warns(TessellationWarning, match=r"face 79 \(BSplineSurface\)"):
        part = tessellate(solid.shape, name="featuretype", tolerance_mm=0.05, budget=budget)
    report = part.meta["tessellation"]
    assert report.stopped in ("stalled", "budget") and not report.within_tolerance
    assert report.n_triangles <= budget
    assert report.method == "sampled+projected"
    assert report.max_chord_error_mm < 0.2  # the best mesh is kept, not the last


def test_tiny_tolerance_is_meshed_within_the_budget_up_front():
    import cadquery as cq

    sphere = cq.Workplane().sphere(20.0)
    budget = 5000
    with pytest.warns(TessellationWarning, match="would need about"):
        part = tessellate(sphere, name="ball", tolerance_mm=1e-6, budget=budget)
    report = part.meta["tessellation"]
    assert report.n_triangles <= budget and report.stopped == "budget"
    # the sagitta of a sphere's facets (independent check): error ~ h^2 / (8 R) for facet size h
    assert 0 < report.max_chord_error_mm < 20.0 * 0.05


def test_budget_from_the_environment_is_checked(monkeypatch):
    from geometry.mesh import GeometryError
    from geometry.tessellate import ENV_BUDGET, triangle_budget

    monkeypatch.setenv(ENV_BUDGET, "1e5")
    assert triangle_budget() == 100_000
    monkeypatch.setenv(ENV_BUDGET, "lots")
    with pytest.raises(GeometryError, match="STRAYLIGHT_TRIANGLE_BUDGET"):
        triangle_budget()


def _unsewn_box():
    """A 10 mm box whose six faces are separate copies (no shared edges), its top face 0.5 um too high: an
    open B-rep as CAD exchange files can hold (sewing at 1 um closes it; merging nodes at 1e-7 mm does not)."""
    import cadquery as cq
    from OCP.BRepBuilderAPI import BRepBuilderAPI_Copy

    from geometry.cad import compound_of

    box = cq.Workplane().box(10, 10, 10)
    top = box.faces(">Z").val()
    faces = [BRepBuilderAPI_Copy(f.translate(cq.Vector(0, 0, 5e-4)).wrapped if f.isSame(top) else f.wrapped).Shape()
             for f in box.faces().vals()]
    return compound_of(faces)


def test_open_solid_is_healed_by_sewing():
    part = tessellate(_unsewn_box(), name="box", kind="solid", tolerance_mm=0.1)
    report = part.meta["tessellation"]
    assert report.n_open_edges == 0 and part.is_watertight
    assert "healed by sewing" in report.note


def test_open_solid_left_open_is_reported_with_its_faces():
    with pytest.warns(TessellationWarning, match=r"mesh open: \d+ open edges along B-rep faces \d"):
        part = tessellate(_unsewn_box(), name="box", kind="solid", tolerance_mm=0.1, heal=False)
    report = part.meta["tessellation"]
    assert report.n_open_edges > 0 and not part.is_watertight
    assert "power ledger still closes" in report.note


def test_a_stalled_file_is_reported_once_with_its_faces_and_what_to_do(tmp_path, monkeypatch):
    """One warning per file on the run that meshes it (naming the solid, its chord error and face 79, and what
    to do); none when the same meshes come from the cache (the warning repeated on every command)."""
    import warnings

    from geometry.cad_child import ENV_ISOLATE
    from geometry.io import tessellate_cad

    monkeypatch.setenv("STRAYLIGHT_CACHE", "on")
    monkeypatch.setenv("STRAYLIGHT_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv(ENV_ISOLATE, "off")
    with warnings.catch_warnings(record=True) as cold:
        warnings.simplefilter("always")
        tessellate_cad(FEATURETYPE, tolerance_mm=0.05)
    messages = [str(w.message) for w in cold if issubclass(w.category, TessellationWarning)]
    assert len(messages) == 1, messages
    assert "1 solid(s) not meshed within 0.05 mm" in messages[0] and "face 79 (BSplineSurface)" in messages[0]
    assert "coarser tolerance_mm" in messages[0] and "Said once" in messages[0]
    with warnings.catch_warnings(record=True) as warm:
        warnings.simplefilter("always")
        items = tessellate_cad(FEATURETYPE, tolerance_mm=0.05)
    assert not [w for w in warm if issubclass(w.category, TessellationWarning)]
    assert not items[0][3].meta["tessellation"].within_tolerance  # the report is kept with the cached mesh


def test_a_long_read_prints_progress_lines_that_reach_a_log(tmp_path, monkeypatch, capfd):
    """A file meshed in the child process: a plain line every interval on stderr (a log file gets them too)."""
    from geometry.cad_child import ENV_ISOLATE
    from geometry.io import tessellate_cad

    monkeypatch.setenv("STRAYLIGHT_CACHE", "off")
    monkeypatch.setenv(ENV_ISOLATE, "on")
    monkeypatch.setenv("STRAYLIGHT_PROGRESS_INTERVAL_S", "0.2")
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tessellate_cad(FEATURETYPE, tolerance_mm=0.05)
    lines = [line for line in capfd.readouterr().err.splitlines() if line.startswith("reading and meshing")]
    assert lines and all("featuretype.STEP" in line for line in lines), lines
