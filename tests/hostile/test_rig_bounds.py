"""The rig refuses, before anything moves, a plan whose points would never finish and a
detector gain that would turn every reading into NaN (main 13a6b5b: 'n_readings': 1000000000 never
finished a point; gain_v_per_w = 0 or below ran a whole scan of NaN with exit 0)."""
from __future__ import annotations

import json

import pytest

from rig.plans import MAX_N_READINGS, PlanError, plan_spec_from_dict
from rig.run import HardwareConfigError, check_gain, load_hardware_config
from straylight.cli.main import main

PLAN = {"incidence": [{"theta_i_deg": 30, "theta_r_deg": [0, 20]}]}


def test_plan_with_a_billion_readings_refused(tmp_path, capsys):
    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps({**PLAN, "n_readings": 1_000_000_000}))
    out = tmp_path / "x.csv"
    assert main(["rig", "scan", "--sim", "--sample", "z302_sample_a", "--plan", str(plan), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "'n_readings' = 1000000000 is above 1000" in err
    assert not out.exists()


def test_plan_readings_limit_edges():
    assert plan_spec_from_dict({**PLAN, "n_readings": MAX_N_READINGS}).n_readings == MAX_N_READINGS
    with pytest.raises(PlanError, match="above 1000"):
        plan_spec_from_dict({**PLAN, "n_readings": MAX_N_READINGS + 1})


@pytest.mark.parametrize("gain", [0.0, -5.0, float("nan"), float("inf"), "x"])
def test_bad_gain_refused(gain):
    with pytest.raises(HardwareConfigError, match="gain_v_per_w must be"):
        check_gain(gain)


@pytest.mark.parametrize("gain", ["0.0", "-1000.0"])
def test_hardware_config_with_bad_gain_refused_before_any_device(tmp_path, capsys, gain):
    config = tmp_path / "rig.toml"
    config.write_text(f'gain_v_per_w = {gain}\n[motion]\nresource = "GPIB0::1::INSTR"\n'
                      '[lockin]\nresource = "GPIB0::8::INSTR"\n')
    with pytest.raises(HardwareConfigError, match=r"rig.toml: gain_v_per_w must be a finite number > 0"):
        load_hardware_config(config)
    out = tmp_path / "x.csv"
    assert main(["rig", "scan", "--hardware", str(config), "--sample", "x", "-o", str(out)]) == 2
    assert "gain_v_per_w must be a finite number > 0" in capsys.readouterr().err
    assert not out.exists()
