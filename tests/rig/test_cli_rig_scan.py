"""``straylight rig scan`` end to end (CONTRACTS §4.4), in subprocesses like a user would run it."""
import json
import math
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from materials.scan import read_scan
from rig.writer import read_log
from test_faults_support import assert_same_scan

CLI = [sys.executable, "-m", "straylight.cli.main"]
PLAN = {"name": "cli-test", "polarizations": ["s"],
        "incidence": [{"theta_i_deg": 30, "grid": "paper"}, {"theta_i_deg": 70, "grid": "paper"}]}


def cli(*args, **kw):
    return subprocess.run([*CLI, *map(str, args)], capture_output=True, text=True, timeout=120, **kw)


MODEL = {"name": "cli_glossy", "wavelength_nm": 532.0, "components": [
    {"type": "lambertian", "rd": 0.0004},
    {"type": "k_correlation", "sigma_nm": 15.0, "lc_um": 50.0, "s": 2.5, "n": 1.55}]}


@pytest.fixture(scope="module")
def plan_and_reference(tmp_path_factory):
    # a material file written here (not a preset that may be retuned while the tests run)
    d = tmp_path_factory.mktemp("cli")
    plan, model = d / "plan.json", d / "model.json"
    plan.write_text(json.dumps(PLAN))
    model.write_text(json.dumps(MODEL))
    ref = d / "ref.csv"
    res = cli("rig", "scan", "--sim", "--sample", model, "--plan", plan, "-o", ref, "--seed", 2)
    assert res.returncode == 0, res.stderr
    return plan, model, read_scan(ref), res


def test_sim_scan_writes_contract_csv(plan_and_reference):
    _, _, ref, res = plan_and_reference
    assert "scan complete: 132 of 132 points" in res.stderr
    assert len(ref) == 132 and set(ref.polarization) == {"s"}
    assert set(ref.theta_i_deg) == {30.0, 70.0}
    assert ref.metadata["sample"] == "cli_glossy" and ref.metadata["plan_name"] == "cli-test"
    assert ref.metadata["rig.arm_mm"] == "200.0" and ref.metadata["seed"] == "2"
    # the specular peak is where it should be: theta_r = theta_i
    for ti in (30.0, 70.0):
        sel = ref.theta_i_deg == ti
        assert ref.theta_r_deg[sel][np.argmax(ref.brdf_per_sr[sel])] == pytest.approx(ti, abs=0.3)
    log = ref.path.with_name("ref.log.jsonl")
    assert read_log(log)[-1][1]["exit_status"] == "success"


@pytest.mark.slow  # ~20 s of subprocesses; test_faults.py covers SIGINT/SIGTERM in-process
def test_sigint_leaves_valid_csv_and_resume_matches(plan_and_reference, tmp_path):
    plan, model, ref, _ = plan_and_reference
    out = tmp_path / "int.csv"
    args = [*CLI, "rig", "scan", "--sim", "--sample", str(model), "--plan", str(plan), "-o", str(out),
            "--seed", "2"]
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    n = 0
    while time.monotonic() < deadline and proc.poll() is None:
        try:
            n = len(read_scan(out))
        except ValueError:
            n = 0
        if n >= 3:
            proc.send_signal(signal.SIGINT)
            break
        time.sleep(0.02)
    _, err = proc.communicate(timeout=60)
    assert n >= 3, "scan finished or failed before it could be interrupted"
    assert proc.returncode == 130, err
    assert "interrupted (SIGINT)" in err and "continue with --resume" in err
    partial = read_scan(out)
    assert 3 <= len(partial) < 132
    assert read_log(tmp_path / "int.log.jsonl")[-1][1]["exit_status"] == "abort"
    res = cli(*args[len(CLI):])  # without --resume the file is not touched
    assert res.returncode == 2 and "already exists; use --resume" in res.stderr
    assert res.stderr.strip().count("\n") == 0
    res = cli(*args[len(CLI):], "--resume")
    assert res.returncode == 0, res.stderr
    assert_same_scan(read_scan(out), ref)


def test_hardware_scan_against_pyvisa_sim(tmp_path):
    config = tmp_path / "rig.toml"
    config.write_text(
        'gain_v_per_w = 1000.0\n'
        'laser_watts_per_volt = 0.002\n'
        'move_timeout_s = 2.0\n'
        '[motion]\nresource = "GPIB0::1::INSTR"\nvisa_library = "esp301.yaml@sim"\ntimeout_s = 0.5\n'
        '[lockin]\nresource = "GPIB0::8::INSTR"\nvisa_library = "sr830.yaml@sim"\ntimeout_s = 0.5\n'
        'time_constant_s = 1e-5\n')
    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps({"incidence": [{"theta_i_deg": 30, "theta_r_deg": [0, 20, 30, 60]}]}))
    out = tmp_path / "hw.csv"
    res = cli("rig", "scan", "--hardware", config, "--sample", "wafer-7", "--plan", plan, "-o", out)
    assert res.returncode == 0, res.stderr
    scan = read_scan(out)
    assert len(scan) == 8 and scan.metadata["sample"] == "wafer-7" and scan.metadata["backend"] == "hardware"
    # the simulated SR830 reads X = 1.25 mV and AUX1 = 2.5 V (-> 5 mW); Omega = 0.2 * 5 / 200^2 sr:
    # BRDF = 1.25e-3 / (1000 * 5e-3 * 2.5e-5 * cos theta_r) = 10 / cos theta_r
    expected = 10.0 / np.cos(np.radians(scan.theta_r_deg))
    np.testing.assert_allclose(scan.brdf_per_sr, expected, rtol=1e-9)
    assert math.isclose(float(scan.brdf_std_per_sr.max()), 0.0, abs_tol=1e-9)


@pytest.mark.parametrize("args, message", [
    (["--sim", "--plan", "paper"], "--sample is required"),
    (["--sim", "--sample", "no_such_material"], "unknown material 'no_such_material'"),
    (["--hardware", "missing.toml", "--sample", "x"], "missing.toml: no such hardware config"),
])
def test_bad_input_is_one_line_error(tmp_path, capsys, args, message):
    from straylight.cli.main import main

    assert main(["rig", "scan", *args, "-o", str(tmp_path / "x.csv")]) == 2
    err = capsys.readouterr().err
    assert message in err and err.strip().count("\n") == 0
    assert not (tmp_path / "x.csv").exists()


def test_bad_plan_file_names_line_and_column(tmp_path, capsys):
    from straylight.cli.main import main

    plan = tmp_path / "p.json"
    plan.write_text('{"incidence": [\n {"theta_i_deg": 30 "x": 1}]}')
    assert main(["rig", "scan", "--sim", "--sample", "z302_sample_a", "--plan", str(plan), "-o", str(tmp_path / "x.csv")]) == 2
    assert "p.json, line 2, column 21" in capsys.readouterr().err


def test_help_lists_the_contract_options(capsys):
    from straylight.cli.main import main

    with pytest.raises(SystemExit) as info:
        main(["rig", "scan", "--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    for opt in ("--sim", "--hardware", "--sample", "--plan", "-o", "--seed", "--resume"):
        assert opt in out


def test_sim_effect_injection_moves_the_peak(tmp_path, capsys):
    # PHYSICS §4: a sample-stage offset d moves the specular peak by 2 d in arm angle
    from straylight.cli.main import main

    plan = tmp_path / "p.json"
    plan.write_text(json.dumps({"polarizations": ["s"], "incidence": [{"theta_i_deg": 30, "grid": "paper"}]}))
    model = tmp_path / "m.json"
    model.write_text(json.dumps(MODEL))
    peaks = []
    for name, extra in (("base", []), ("offset", ["--effect", "angle_offset:offset_deg=0.5"])):
        out = tmp_path / f"{name}.csv"
        assert main(["rig", "scan", "--sim", "--sample", str(model), "--plan", str(plan), "-o", str(out), *extra]) == 0
        scan = read_scan(out)
        peaks.append(scan.theta_r_deg[np.argmax(scan.brdf_per_sr)])
    assert peaks[0] == pytest.approx(30.0, abs=0.1)
    assert abs(peaks[1] - peaks[0]) == pytest.approx(1.0, abs=0.15)
    assert main(["rig", "scan", "--sim", "--sample", str(model), "--plan", str(plan), "-o", str(tmp_path / "x.csv"),
                 "--effect", "no_such_effect"]) == 2
    assert "unknown effect 'no_such_effect'" in capsys.readouterr().err


def test_a_negative_seed_is_refused_before_any_file_is_made(tmp_path):
    """It was refused after the scan's CSV and log were made, leaving an empty scan and a --resume hint."""
    out = tmp_path / "x.csv"
    res = cli("rig", "scan", "--sim", "--sample", "z302_sample_b", "-o", out, "--seed", -1)
    err = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert res.returncode == 2 and len(err) == 1 and "--seed must be a non-negative integer" in err[0], res.stderr
    assert not out.exists() and not list(tmp_path.iterdir())
