"""One output rule for every command (atomicio.output_rule, wired in straylight.cli.main): a symbolic link,
a FIFO or one of the command's own inputs is refused as an output before any work, in one line; one run
per output folder (or scan file) at a time, a dead run's lock taken over. All in a private tmp folder:
never /dev."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from straylight.cli.main import main

DATA = Path(__file__).resolve().parents[1] / "data"


def _one_line(capsys, *words):
    err = [e for e in capsys.readouterr().err.strip().splitlines() if e.strip()]
    assert len(err) == 1, err
    for w in words:
        assert w in err[0], err[0]
    return err[0]


@pytest.fixture()
def scene(tmp_path):
    out = tmp_path / "built"
    assert main(["geometry", "build", "tube", "-o", str(out)]) == 0
    return out / "scene.toml"


def test_a_fifo_output_is_refused_before_any_work(tmp_path, scene, capsys):
    fifo = tmp_path / "out.json"
    os.mkfifo(fifo)
    capsys.readouterr()
    assert main(["trace", str(scene), "--rays", "1000", "--json", str(fifo)]) == 2
    _one_line(capsys, "FIFO", str(fifo))
    assert fifo.is_fifo()  # not replaced by a regular file


def test_a_symlink_output_is_refused_and_its_target_kept(tmp_path, scene, capsys):
    target = tmp_path / "precious.json"
    target.write_text('{"mine": true}')
    link = tmp_path / "link.json"
    link.symlink_to(target)
    capsys.readouterr()
    assert main(["trace", str(scene), "--rays", "1000", "--json", str(link)]) == 2
    _one_line(capsys, "symbolic link")
    assert link.is_symlink() and json.loads(target.read_text()) == {"mine": True}
    out_link = tmp_path / "out_link"
    out_link.symlink_to(tmp_path)
    assert main(["pst", str(scene), "--angles-deg", "10", "--rays", "1000", "--out", str(out_link)]) == 2
    _one_line(capsys, "symbolic link", "--out")


def test_an_output_that_is_the_commands_own_input_is_refused(tmp_path, scene, capsys):
    before = scene.read_bytes()
    capsys.readouterr()
    assert main(["trace", str(scene), "--rays", "1000", "--json", str(scene)]) == 2
    _one_line(capsys, "own inputs")
    assert scene.read_bytes() == before
    scan = tmp_path / "scan.csv"
    scan.write_text("theta_i_deg,theta_r_deg,phi_r_deg,polarization,wavelength_nm,brdf_per_sr\n"
                    "30,0,0,s,532,0.01\n30,10,0,s,532,0.012\n30,20,0,s,532,0.015\n")
    kept = scan.read_bytes()
    assert main(["material", "fit", str(scan), "-o", str(scan)]) == 2
    _one_line(capsys, "own inputs", "destroy")
    assert scan.read_bytes() == kept


def test_one_run_per_out_folder(tmp_path, scene, capsys):
    out = tmp_path / "pst"
    out.mkdir()
    holder = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        (out / ".straylight-lock").write_text(json.dumps({"pid": holder.pid, "host": os.uname().nodename,
                                                          "started": "2026-12-05T12:00:00"}))
        capsys.readouterr()
        assert main(["pst", str(scene), "--angles-deg", "10", "--rays", "1000", "--out", str(out)]) == 2
        line = _one_line(capsys, "in use by another straylight run", str(holder.pid))
        assert "choose another path" in line
        assert not (out / "pst.json").exists()
    finally:
        holder.kill()
        holder.wait()
    # the holder is gone: its lock is taken over with a warning, the run goes on and releases it
    assert main(["pst", str(scene), "--angles-deg", "10", "--rays", "1000", "--out", str(out)]) == 0
    assert "taking over the lock" in capsys.readouterr().err
    assert (out / "pst.json").exists() and not (out / ".straylight-lock").exists()


def test_a_refused_run_leaves_no_empty_folder_behind(tmp_path, capsys):
    out = tmp_path / "never"
    assert main(["pst", str(tmp_path / "missing.toml"), "--angles-deg", "10", "--rays", "1000",
                 "--out", str(out)]) == 2
    assert not out.exists()
