"""Edge diffraction plumbing (CONTRACTS §6.5): which edges diffract, the scene keys, the
command line, and the engine invariants (ledger, seeds, batch sizes) with diffraction on."""
from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import trimesh

from geometry.edges import sharp_edges
from straylight.scene import SceneFileError, load_scene
from straylight.trace import EstimatorOptions, OutputOptions, PhysicsOptions, TraceOptions

pytestmark = pytest.mark.filterwarnings("ignore::UserWarning")  # open analytic planes are not watertight

STOP_SCENE = """
[material.black]
components = [{{type = "lambertian", rd = 0.5}}]

[[part]]
name = "stop"
surface = {{type = "plane", vertex_mm = [0.0, 0.0, 0.0], axis = [0.0, 0.0, 1.0], outer_radius_mm = 2.0, inner_radius_mm = 0.2}}
material = "black"
{diffraction}

[[part]]
name = "screen"
surface = {{type = "plane", vertex_mm = [0.0, 0.0, -50.0], axis = [0.0, 0.0, 1.0], outer_radius_mm = 30.0}}
role = "detector"

[[source]]
type = "collimated_disk"
center_mm = [0.0, 0.0, 5.0]
normal = [0.0, 0.0, -1.0]
direction = [0.0, 0.0, -1.0]
radius_mm = 0.3
{wavelength}
"""


def write_scene(tmp_path, diffraction='diffraction = "edges"', wavelength="wavelength_nm = 10000.0"):
    path = tmp_path / "stop.toml"
    path.write_text(STOP_SCENE.format(diffraction=diffraction, wavelength=wavelength))
    return path


def test_box_edges_all_sharp_and_cylinder_only_its_rims():
    """A box's 12 edges turn by 90 deg; a 64-sided tube's side edges turn by 5.6 deg (< 60), so only
    its two rims (2 x 64 segments) diffract; an open sheet's border diffracts."""
    box = trimesh.creation.box(extents=(1.0, 2.0, 3.0))
    e = sharp_edges(box.vertices, box.faces)
    assert len(e) == 12 and np.allclose(e.turn_deg, 90.0)
    cyl = trimesh.creation.cylinder(radius=5.0, height=2.0, sections=64)
    e = sharp_edges(cyl.vertices, cyl.faces)
    assert len(e) == 128
    z = np.concatenate([e.start_mm[:, 2], e.end_mm[:, 2]])
    assert np.allclose(np.abs(z), 1.0)  # only at the two ends
    sheet = sharp_edges(np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float), np.array([[0, 1, 2], [0, 2, 3]]))
    assert len(sheet) == 4 and np.allclose(sheet.turn_deg, 180.0)


def test_scene_keys_mark_the_part_and_the_wavelength(tmp_path):
    rs = load_scene(write_scene(tmp_path))
    assert rs.scene.part("stop").meta["diffraction"] == "edges"
    assert rs.sources[0].wavelength_nm == 10000.0
    assert "diffraction" not in rs.scene.part("screen").meta


@pytest.mark.parametrize("diffraction, wavelength, message", [
    ('diffraction = "edge"', "wavelength_nm = 500.0", 'diffraction must be "edges"'),
    ('diffraction = "edges"', "wavelength_nm = -1.0", "wavelength_nm must be > 0"),
])
def test_bad_keys_are_one_line_errors(tmp_path, diffraction, wavelength, message):
    with pytest.raises(SceneFileError, match=message):
        load_scene(write_scene(tmp_path, diffraction, wavelength))


def test_missing_wavelength_is_refused(tmp_path):
    rs = load_scene(write_scene(tmp_path, wavelength=""))
    with pytest.raises(ValueError, match="'stop' diffracts .* give wavelength_nm on the \\[\\[source\\]\\]"):
        rs.trace(100, seed=1)


@pytest.mark.parametrize("command", [["trace", "--rays", "100", "--json", "{d}/t.json"],
                                     ["pst", "--angles-deg", "1", "--rays", "100", "--out", "{d}/o"]])
def test_missing_wavelength_names_the_scene_file_on_the_command_line(tmp_path, capsys, command):
    from straylight.cli.main import main

    path = write_scene(tmp_path, wavelength="")
    assert main([command[0], str(path), *(a.format(d=tmp_path) for a in command[1:])]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"{path}: 'stop' diffracts" in err
    # the beam's wavelength given on the command line is enough (docs/diffraction.md)
    if command[0] == "pst":
        assert main(["pst", str(path), "--angles-deg", "1", "--rays", "100", "--wavelength-nm", "500",
                     "--out", str(tmp_path / "o500")]) == 0


def test_diffraction_off_is_the_geometric_trace(tmp_path):
    """--diffraction off traces exactly as a scene without the key (same bits)."""
    a = load_scene(write_scene(tmp_path)).trace(3000, seed=2, options=TraceOptions(physics=PhysicsOptions(diffraction="off")))
    b = load_scene(write_scene(tmp_path, diffraction="")).trace(3000, seed=2)
    assert a.detectors["screen"].power_w == b.detectors["screen"].power_w
    assert a.absorbed["stop"].power_w == b.absorbed["stop"].power_w


def test_diffraction_same_numbers_any_batch_size_and_ledger_closes(tmp_path):
    """Seeds and batch sizes (CONTRACTS §1) with diffraction, scatter and NEE on; the ledger closes."""
    rs = load_scene(write_scene(tmp_path))
    runs = [rs.trace(5000, seed=4, options=TraceOptions(output=OutputOptions(record_paths=True), batch_rays=b)) for b in (1000, 5000)]
    assert runs[0].detectors["screen"].power_w == runs[1].detectors["screen"].power_w
    assert runs[0].detectors["screen"].stderr_w == runs[1].detectors["screen"].stderr_w
    for r in runs:
        assert abs(r.ledger["balance_residual_w"]) < 1e-9
    kinds = {k for g in runs[0].paths.group() for _, k in g.events}
    assert "diffraction" in kinds  # at 10 um, 0.3 mm from a 0.2 mm hole: most of the light bends


def test_trace_command_with_diffraction(tmp_path):
    scene = write_scene(tmp_path)
    out = tmp_path / "out.json"
    run = subprocess.run([sys.executable, "-m", "straylight.cli.main", "trace", str(scene), "--rays", "2000",
                          "--seed", "1", "--json", str(out)], capture_output=True, text=True, check=False)
    assert run.returncode == 0, run.stderr
    doc = json.loads(out.read_text())
    total = sum(d["power_w"] for d in doc["detectors"].values()) + sum(a["power_w"] for a in doc["absorbed"].values()) \
        + doc["escaped_w"]
    assert abs(total - doc["emitted_w"]) < 1e-9
    bad = tmp_path / "bad.toml"
    bad.write_text(textwrap.dedent(scene.read_text()).replace('diffraction = "edges"', 'diffraction = "yes"'))
    run = subprocess.run([sys.executable, "-m", "straylight.cli.main", "trace", str(bad), "--rays", "10",
                          "--json", str(tmp_path / "b.json")], capture_output=True, text=True, check=False)
    assert run.returncode != 0 and len(run.stderr.strip().splitlines()) == 1 and "'stop'" in run.stderr


OFF_AXIS_SCENE = """
[[part]]
name = "stop"
surface = {type = "plane", vertex_mm = [0.0, 0.0, 0.0], axis = [0.0, 0.0, 1.0], outer_radius_mm = 2.0, inner_radius_mm = 0.2}
role = "absorber"
diffraction = "edges"

[[part]]
name = "spot"
surface = {type = "plane", vertex_mm = [4.0, 0.0, -50.0], axis = [0.0, 0.0, 1.0], outer_radius_mm = 1.5}
role = "detector"

[[source]]
type = "collimated_disk"
center_mm = [0.0, 0.0, 5.0]
normal = [0.0, 0.0, -1.0]
direction = [0.0, 0.0, -1.0]
radius_mm = 0.25
wavelength_nm = 10000.0
"""


def test_next_event_estimation_from_bends_agrees_with_the_analog_walk(tmp_path):
    """Light bent by a hole's rim onto a detector 4.6 deg off axis (no geometric path): NEE from the
    diffraction vertices (HURB's density in solid angle) and the analog walk agree within 4 combined
    standard errors, and NEE lowers the error (it engages: detector_nee > 0)."""
    path = tmp_path / "off.toml"
    path.write_text(OFF_AXIS_SCENE)
    rs = load_scene(path)
    nee = rs.trace(20_000, seed=7, options=TraceOptions(estimator=EstimatorOptions(nee=True)))
    walk = rs.trace(20_000, seed=8, options=TraceOptions(estimator=EstimatorOptions(nee=False)))
    a, b = nee.detectors["spot"], walk.detectors["spot"]
    assert b.power_w > 0 and nee.ledger["detector_nee"]["spot"].power_w > 0
    assert abs(a.power_w - b.power_w) <= 4 * np.hypot(a.stderr_w, b.stderr_w), (a, b)
    assert a.stderr_w < 0.5 * b.stderr_w
    assert abs(nee.ledger["balance_residual_w"]) < 1e-9


def test_compiled_walk_equals_numpy_reference_with_diffraction(tmp_path):
    """The compiled kernels and their numpy twins give the same bits with bends and their NEE."""
    from straylight.trace import make_spec, run_batch, run_batch_reference

    path = tmp_path / "off.toml"
    path.write_text(OFF_AXIS_SCENE)
    rs = load_scene(path)
    spec = make_spec(rs.scene, rs.sources, 2000, 3, rs.materials, TraceOptions(output=OutputOptions(record_paths=True)))
    a, b = run_batch(spec, 0, 2), run_batch_reference(spec, 0, 2)
    assert set(a) == set(b)
    for key in a:
        if isinstance(a[key], np.ndarray):
            np.testing.assert_array_equal(a[key], b[key], err_msg=key)


def test_band_prisms_find_every_ray_that_passes_a_segment():
    """The embree pre-selection (band prisms) never drops a passage the full segment search finds:
    rays aimed within ~1 band of random points on a box's edges, from every direction."""
    from straylight.engine.edge_index import band_prisms, edge_table, passages
    from straylight.intersect.embree import EmbreeIntersector

    box = trimesh.creation.box(extents=(10.0, 20.0, 1.0))
    table = edge_table([(0, sharp_edges(box.vertices, box.faces))], [], band_mm=0.05)
    rng = np.random.default_rng(0)
    n = 50_000
    k = rng.integers(0, len(table.seg_a), n)
    p = table.seg_a[k] + rng.random(n)[:, None] * (table.seg_b[k] - table.seg_a[k]) + rng.normal(size=(n, 3)) * 0.05
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o, tmax = p - 5 * d, np.full(n, 10.0)
    full = passages(table, o, d, tmax)[0]
    near = EmbreeIntersector(band_prisms(table)).occluded(o, d, tmax)
    assert (full >= 0).sum() > 1000  # many rays do pass an edge
    np.testing.assert_array_equal(passages(table, o, d, tmax, near=near)[0], full)


def test_pst_command_with_and_without_diffraction(tmp_path):
    """`straylight pst --diffraction on|off` (and --wavelength-nm): pst.json says which, and the light
    bent onto the off-axis spot is there only with diffraction on."""
    path = tmp_path / "off.toml"
    path.write_text(OFF_AXIS_SCENE)
    docs = {}
    for flag in ("on", "off"):
        out = tmp_path / flag
        run = subprocess.run([sys.executable, "-m", "straylight.cli.main", "pst", str(path), "--angles-deg", "0",
                              "--rays", "3000", "--seed", "1", "--diffraction", flag, "--wavelength-nm", "20000",
                              "--out", str(out)], capture_output=True, text=True, check=False)
        assert run.returncode == 0, run.stderr
        docs[flag] = json.loads((out / "pst.json").read_text())
    on, off = docs["on"]["diffraction"], docs["off"]["diffraction"]
    assert on["on"] and "HURB" in on["method"] and on["wavelength_nm"] == 20000.0 and on["parts"] == ["stop"]
    assert off["on"] is False
    assert docs["on"]["points"][0]["pst"] > 0 and docs["off"]["points"][0]["pst"] == 0


def test_ray_log_follows_rays_through_a_bend(tmp_path):
    """The ray log (what the 3-D view draws) keeps a bent ray going: the segment that ends at the edge
    (SEGMENT_BEND) is followed by the bent ray's own segment from that point, under the same ray id."""
    from straylight.engine.ray_log import SEGMENT_BEND

    res = load_scene(write_scene(tmp_path)).trace(400, seed=5, options=TraceOptions(output=OutputOptions(ray_log=400)))
    log = res.ray_log
    bends = np.flatnonzero(log.tri == SEGMENT_BEND)
    assert len(bends) > 0  # at 10 um most rays through the 0.2 mm hole bend
    followed = 0
    for i in bends:
        nxt = i + 1
        if nxt < len(log) and log.ray[nxt] == log.ray[i]:
            np.testing.assert_allclose(log.origin_mm[nxt], log.end_mm[i], atol=1e-6)
            assert log.kind[nxt] == 3  # the segment leaves a bend (EVENT_DIFFRACTION)
            assert not np.allclose(log.direction[nxt], log.direction[i])  # it changed direction there
            followed += 1
    assert followed == len(bends)
