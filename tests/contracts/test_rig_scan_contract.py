"""CONTRACTS §4.4 ``straylight rig scan`` and the §2 CSV it writes, read here with the csv module
(not the project's reader): new material file, custom plan, paper plan, SIGINT/SIGTERM mid-run and
``--resume`` (no duplicated or skipped point), errors.
"""
import csv
import json
import math
import signal
import subprocess
import time

import numpy as np
import pytest

from contract_helpers import CONSOLE, assert_one_line_error, write_json

COLUMNS = ["wavelength_nm", "polarization", "theta_i_deg", "theta_r_deg", "phi_r_deg", "brdf_per_sr",
           "brdf_std_per_sr", "n_repeats"]
RD = 0.06


def parse_csv(path):
    """Independent CONTRACTS §2 parser: (metadata, rows as dicts); asserts the layout."""
    meta, rows, header = {}, [], None
    text = path.read_text(encoding="utf-8")
    assert text.endswith("\n"), "last line is incomplete"
    for line in text.splitlines():
        if header is None and line.startswith("#"):
            key, sep, value = line[1:].partition(":")
            assert sep, f"metadata line not '# key: value': {line!r}"
            meta[key.strip()] = value.strip()
            continue
        cells = next(csv.reader([line]))
        if header is None:
            header = cells
            assert header == COLUMNS
            continue
        assert len(cells) == len(COLUMNS), line
        row = dict(zip(COLUMNS, cells))
        for k in COLUMNS:
            if k != "polarization":
                row[k] = float(row[k])
        assert row["polarization"] in ("s", "p", "u")
        assert -90 <= row["theta_i_deg"] <= 90 and -90 <= row["theta_r_deg"] <= 90
        assert row["brdf_std_per_sr"] >= 0 and row["n_repeats"] == int(row["n_repeats"])
        rows.append(row)
    assert header is not None
    return meta, rows


def key(row):
    return (row["polarization"], row["theta_i_deg"], row["theta_r_deg"], row["phi_r_deg"])


def _material(tmp_path):
    return write_json(tmp_path / "grey_paint.json", {"name": "grey_paint", "wavelength_nm": 780.0,
                                                     "components": [{"type": "lambertian", "rd": RD}]})


def _plan(tmp_path, n=40):
    trs = [round(float(x), 2) for x in np.linspace(2.0, 84.0, n)]  # backscatter: every 4th, arm soft limits
    return write_json(tmp_path / "plan.json", {"name": "contract-plan", "n_readings": 4, "polarizations": ["s", "p"],
                                               "incidence": [{"theta_i_deg": 25, "theta_r_deg": trs},
                                                             {"theta_i_deg": 62, "theta_r_deg": [t for t in trs[::4] if t < 55],
                                                              "phi_r_deg": 180, "polarizations": ["p"]}]})


def test_sim_scan_custom_plan_new_material(cli, tmp_path):
    out = tmp_path / "scan.csv"
    rc, _, err = cli("rig", "scan", "--sim", "--sample", _material(tmp_path), "--plan", _plan(tmp_path, 12),
                     "-o", out, "--seed", 7)
    assert rc == 0, err
    meta, rows = parse_csv(out)
    for k in ("sample", "rig.arm_mm", "rig.slit_width_mm", "rig.slit_height_mm", "rig.beam_diameter_mm",
              "rig.sample_width_mm", "date"):
        assert k in meta, f"metadata {k!r} missing"
    float(meta["rig.arm_mm"])
    n_back = len([t for t in np.linspace(2.0, 84.0, 12)[::4] if t < 55])
    assert len(rows) == 2 * 12 + n_back
    assert len({key(r) for r in rows}) == len(rows)
    assert {r["n_repeats"] for r in rows} == {4.0}
    assert {r["wavelength_nm"] for r in rows} == {780.0}
    back = [r for r in rows if r["theta_i_deg"] == 62]
    assert len(back) == n_back and all(r["polarization"] == "p" for r in back)
    # backscatter half-plane written either as phi_r = 180 or as a negative theta_r (CONTRACTS §1/§2)
    assert all(r["phi_r_deg"] == 180 or r["theta_r_deg"] < 0 for r in back)
    # a Lambertian sample reads rd / pi wherever the detector sees the lit sample (mean over points,
    # noise is a few per cent per point; 15 % covers the rig's slit/footprint averaging)
    f = np.array([r["brdf_per_sr"] for r in rows if abs(r["theta_r_deg"]) < 60])
    assert np.median(f) == pytest.approx(RD / math.pi, rel=0.15)
    # same seed, same numbers; another seed, other numbers
    out2, out3 = tmp_path / "again.csv", tmp_path / "other.csv"
    for o, s in ((out2, 7), (out3, 8)):
        rc, _, err = cli("rig", "scan", "--sim", "--sample", _material(tmp_path), "--plan", tmp_path / "plan.json",
                         "-o", o, "--seed", s)
        assert rc == 0, err
    assert parse_csv(out2)[1] == rows
    assert parse_csv(out3)[1] != rows


def test_sim_scan_preset_sample(cli, tmp_path):
    from materials import list_presets, load_material

    name = list_presets()[-1]
    plan = write_json(tmp_path / "tiny.json", {"incidence": [{"theta_i_deg": 33, "theta_r_deg": [10, 33, 60]}]})
    out = tmp_path / "new" / "dir" / "preset.csv"  # parent directories are created
    rc, _, err = cli("rig", "scan", "--sim", "--sample", name, "--plan", plan, "-o", out)
    assert rc == 0, err
    meta, rows = parse_csv(out)
    assert meta["sample"] == name and len(rows) == 3 * len({r["polarization"] for r in rows})
    assert {r["wavelength_nm"] for r in rows} == {load_material(name).wavelength_nm}


def test_paper_plan_points():
    """--plan paper: incidence 10, 30, 40, 70, 80; s and p; 0.5/0.2/0.05 deg steps near specular, 5 deg off."""
    from rig.plans import load_plan

    spec = load_plan("paper")
    assert spec.n_readings == 3
    pts = [tuple(p) for p in spec.points]
    assert len(set(pts)) == len(pts)
    ti = sorted({p.theta_i_deg for p in spec.points})
    assert ti == [10, 30, 40, 70, 80]
    assert {p.polarization for p in spec.points} == {"s", "p"}
    for t in ti:
        tr = np.array(sorted({p.theta_r_deg for p in spec.points if p.theta_i_deg == t and p.polarization == "s"}))
        steps = np.round(np.diff(tr), 6)
        assert {0.05, 0.2, 0.5, 5.0} <= set(steps.tolist()), (t, sorted(set(steps.tolist())))
        assert t in tr
        near = tr[np.abs(tr - t) < 0.5 - 1e-9]
        assert np.allclose(np.diff(near), 0.05)  # finest step around specular
        far = tr[np.abs(tr - t) > 6]
        assert np.allclose(np.diff(far)[np.abs(np.diff(far)) < 10], 5.0, atol=1e-9) or len(far) < 2


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_interrupt_then_resume(tmp_path, sig):
    mat, plan = _material(tmp_path), _plan(tmp_path, 80)
    out = tmp_path / "int.csv"
    argv = [str(CONSOLE), "rig", "scan", "--sim", "--sample", str(mat), "--plan", str(plan), "-o", str(out),
            "--seed", "3"]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 60
    while time.time() < deadline:
        if out.exists() and out.read_text().count("\n") > 40 or proc.poll() is not None:
            break
        time.sleep(0.05)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode != 0, "an interrupted scan must not exit 0"
    assert "Traceback" not in err
    _, partial = parse_csv(out)
    n_plan = 2 * 80 + len([t for t in np.linspace(2.0, 84.0, 80)[::4] if t < 55])
    assert 0 < len(partial) < n_plan, "interrupt came too late to test anything"
    assert len({key(r) for r in partial}) == len(partial)
    log = out.with_suffix(".log.jsonl")
    docs = [json.loads(line) for line in log.read_text().splitlines()]
    # a complete document log of [name, doc] lines (CONTRACTS 4.4), valid under event-model's schemas
    from event_model import DocumentNames, schema_validators

    assert all(isinstance(d, list) and len(d) == 2 for d in docs)
    for name, doc in docs:
        schema_validators[DocumentNames[name]].validate(doc)
    assert docs[0][0] == "start" and docs[-1][0] == "stop"
    assert docs[-1][1]["exit_status"] == "abort" and sig.name in docs[-1][1]["reason"]
    from materials.scan import read_scan

    assert len(read_scan(out)) == len(partial)
    r = subprocess.run(argv + ["--resume"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    _, full = parse_csv(out)
    assert full[:len(partial)] == partial  # the completed points are kept as they were
    assert len(full) == n_plan and len({key(r) for r in full}) == n_plan
    # the same set of points as an uninterrupted run of the plan
    from rig.plans import load_plan

    expect = {(p.polarization, float(p.theta_i_deg), float(p.theta_r_deg), float(p.phi_r_deg))
              for p in load_plan(plan).points}
    got = {key(r) for r in full}
    folded = {(k[0], k[1], abs(k[2]), 180.0 if k[2] < 0 else k[3]) for k in got}
    assert folded == expect


def test_scan_errors(cli, tmp_path):
    out = tmp_path / "e.csv"
    rc, _, err = cli("rig", "scan", "--sim", "--sample", "no_such_sample", "--plan", _plan(tmp_path, 3), "-o", out)
    assert_one_line_error(rc, err, "no_such_sample")
    bad_plan = tmp_path / "bad_plan.json"
    bad_plan.write_text('{"incidence": [\n {"theta_i_deg": 20, "theta_r_deg": [1, 2],}\n]}')
    rc, _, err = cli("rig", "scan", "--sim", "--sample", _material(tmp_path), "--plan", bad_plan, "-o", out)
    assert_one_line_error(rc, err, "bad_plan.json", "line 2")
    rc, _, err = cli("rig", "scan", "--sim", "--plan", tmp_path / "plan.json", "-o", out)
    assert_one_line_error(rc, err, "--sample")
    rc, _, err = cli("rig", "scan", "--sim", "--sample", _material(tmp_path), "--plan", tmp_path / "plan.json",
                     "-o", out, "--seed", 1)
    assert rc == 0, err
    before = out.read_text()
    rc, _, err = cli("rig", "scan", "--sim", "--sample", _material(tmp_path), "--plan", tmp_path / "plan.json",
                     "-o", out, "--seed", 1)
    assert_one_line_error(rc, err, "e.csv")  # no silent overwrite
    assert out.read_text() == before
    rc, _, err = cli("rig", "scan", "--sim", "--sample", _material(tmp_path), "--plan", tmp_path / "plan.json",
                     "-o", out, "--seed", 1, "--resume")
    assert rc == 0, err  # resuming a complete scan adds nothing
    assert out.read_text() == before
