"""Input files must be regular files of sane size, and requests beyond the machine are refused up
front with the estimate: ``material = "/dev/zero"`` or a FIFO in a scene, a FIFO
as the scene itself, ``--rays 99999999999999999999``, ``--tolerance-mm 1e-6``: each ends in one
line naming what is wrong, at once (each command runs under a 60 s timeout that a hang would hit;
the FIFOs have no writer, so a read would block forever)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from atomicio.inputs import InputFileError, check_input_file, read_input_text
from straylight.budget import chunk_tally_bytes, check_ray_budget
from straylight.cli.main import main

GOLDEN = Path(__file__).resolve().parents[1] / "data" / "engine_golden"
SOURCE = """
[[source]]
type = "collimated_disk"
center_mm = [0.0, 0.0, 310.0]
normal = [0.0, 0.0, -1.0]
direction = [0.0, 0.0, -1.0]
radius_mm = 60.0
power_w = 1.0
"""


def _scene(tmp_path, material=None, mesh=None, extra=""):
    mesh = mesh or next(GOLDEN.glob("*.stl"))
    text = f'[[part]]\nname = "tube"\nmesh = "{mesh}"\nmaterial = "{material or "black"}"\n{extra}\n' + SOURCE
    if material is None:
        text = '[material.black]\ncomponents = [{type = "lambertian", rd = 0.05}]\n' + text
    path = tmp_path / "scene.toml"
    path.write_text(text)
    return path


def _cli(args, timeout=60):
    """The real command in a subprocess: a hang is a timeout (a failed test), not a stuck suite."""
    return subprocess.run([sys.executable, "-m", "straylight.cli.main", *map(str, args)], capture_output=True,
                          text=True, timeout=timeout)


@pytest.fixture
def fifo(tmp_path):
    path = tmp_path / "pipe.json"
    os.mkfifo(path)
    return path


@pytest.mark.parametrize("material", ["/dev/zero", "FIFO"])
def test_material_that_is_not_a_regular_file_is_one_line(tmp_path, fifo, material):
    material = {"FIFO": str(fifo)}.get(material, material)
    res = _cli(["trace", _scene(tmp_path, material=material), "--rays", "1000", "--json", tmp_path / "o.json"])
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2 and len(lines) == 1, res.stderr
    assert material in lines[0] and "not a regular file" in lines[0]


def test_scene_and_mesh_that_are_not_regular_files(tmp_path, fifo, capsys):
    assert main(["trace", str(fifo), "--rays", "1000", "--json", str(tmp_path / "o.json")]) == 2
    err = capsys.readouterr().err
    assert "FIFO" in err and str(fifo) in err
    assert main(["trace", str(_scene(tmp_path, mesh="/dev/zero")), "--rays", "1000",
                 "--json", str(tmp_path / "o.json")]) == 2
    assert "/dev/zero: mesh file" in capsys.readouterr().err
    assert main(["trace", str(_scene(tmp_path, material=str(tmp_path))), "--rays", "1000",
                 "--json", str(tmp_path / "o.json")]) == 2
    assert f"{tmp_path}: material file is a folder" in capsys.readouterr().err


def test_reader_limits(tmp_path):
    big = tmp_path / "big.json"
    big.write_bytes(b" " * 2048)
    with pytest.raises(InputFileError, match="more than the 1.0 KB"):
        read_input_text(big, "material file", max_bytes=1024)
    assert read_input_text(big, "material file", max_bytes=4096) == " " * 2048
    with pytest.raises(InputFileError, match="character device"):
        check_input_file("/dev/zero", "material file")


def test_rays_beyond_the_machine_refused_with_the_estimate(tmp_path, capsys):
    code = main(["trace", str(GOLDEN / "tube.toml"), "--rays", "99999999999999999999",
                 "--json", str(tmp_path / "o.json")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "--rays 1e+20" in err[0] and "GB" in err[0] and "years" in err[0]
    # the estimate itself: 1e17 chunks x 272 bytes (one detector) = 2.7e19 bytes
    assert chunk_tally_bytes(1) == 2 * (112 + 8) + 16 + 16
    with pytest.raises(ValueError, match="2.53e"):  # 2.72e19 B / 2**30 = 2.53e10 GB
        check_ray_budget(10**20, 1, memory_bytes=2**34)
    check_ray_budget(10**9, 1, memory_bytes=2**34)  # 1e6 chunks: 0.27 GB of 16: fine
    with pytest.raises(ValueError, match="trace at most"):
        check_ray_budget(10**11, 1, memory_bytes=2**34)  # 27 GB of tallies > 8 GB


def test_tolerance_that_would_mesh_without_bound_is_refused(tmp_path, capsys):
    assert main(["geometry", "build", "tube", "--tolerance-mm", "1e-6", "-o", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err
    assert "1e-06 mm is below" in err and not (tmp_path / "b").exists()
    scene = _scene(tmp_path, extra="tolerance_mm = 1e-6")
    assert main(["trace", str(scene), "--rays", "1000", "--json", str(tmp_path / "o.json")]) == 2
    assert "tolerance_mm: chord tolerance 1e-06 mm" in capsys.readouterr().err


def test_mesh_budget_estimate_refuses_large_parts():
    """3.63 R / t triangles (a sphere of radius R meshed to chord error t; geometry.limits): a 10 m
    box at 1e-4 mm is ~1.8e8 triangles, above what any 24 GB machine meshes; a 100 mm box at
    0.05 mm is ~3.6e3."""
    import cadquery as cq

    from geometry.limits import ToleranceError, check_mesh_budget, estimated_triangles

    assert estimated_triangles(100.0, 0.05) == pytest.approx(4 * 3.141592653589793 / (2 * 3**0.5) * 50 / 0.05)
    small = cq.Solid.makeBox(100.0, 100.0, 100.0)  # bounding-box diagonal 100 sqrt(3) mm
    assert check_mesh_budget([small], 0.05, "t") == pytest.approx(estimated_triangles(100.0 * 3**0.5, 0.05), rel=1e-3)
    huge = cq.Solid.makeBox(10_000.0, 10_000.0, 10_000.0)
    with pytest.raises(ToleranceError, match="more than this machine can mesh"):
        check_mesh_budget([huge], 1e-4, "t")


def test_worker_pools_beyond_the_machine_are_refused(tmp_path, capsys):
    for extra, words in ((["--workers", "100000", "--processes"], "GB for the worker processes"),
                         (["--threads", "100000"], "more than 32 per core")):
        assert main(["trace", str(GOLDEN / "tube.toml"), "--rays", "1000", "--json", str(tmp_path / "o.json"),
                     *extra]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and words in err[0], err
