"""ophyd devices over the simulated and the pyvisa-sim backends.

Protocol checks follow ophyd's own (ophyd/tests/test_bluesky_protocols.py), at run time:
``isinstance`` against bluesky.protocols plus describe/read key agreement.
Expected signals come from the calibration equation V = g P Omega cos(theta_r) f
(seed paper section 2) with a Lambertian sample, f = rd / pi.
"""
import math

import pytest
from bluesky import protocols

from materials.lambertian import Lambertian
from rig.devices import MoveTimeout, SoftLimitError, real_devices, sim_devices
from rig.drivers import InstrumentTimeout, open_resource, sim_library
from rig.drivers.esp301 import Esp301
from rig.drivers.sr830 import Sr830
from rig.instrument import RigConfig
from rig.sim import SimRig


def quiet_sim(rd=0.3, **kw):
    sim = SimRig(Lambertian(rd), RigConfig(), seed=1, ideal=True, noise_rel=0.0, noise_floor_per_sr=0.0, **kw)
    return sim, sim_devices(sim)


def test_devices_satisfy_bluesky_protocols():
    _, d = quiet_sim()
    for dev in d.all():
        assert isinstance(dev, protocols.Readable), dev.name
        assert isinstance(dev, protocols.Configurable), dev.name
        desc, reading = dev.describe(), dev.read()
        assert set(desc) == set(reading), dev.name
        for key, value in reading.items():
            assert {"value", "timestamp"} <= set(value)
            assert {"source", "dtype", "shape"} <= set(desc[key])
    for dev in (d.sample_stage, d.arm, d.hwp):
        assert isinstance(dev, protocols.Movable) and isinstance(dev, protocols.Stoppable)
    for dev in (d.lockin, d.laser, d.chopper):
        assert isinstance(dev, protocols.Triggerable)
    assert set(d.lockin.read()) == {"lockin_mean_v", "lockin_std_v", "lockin_n", "lockin_discarded"}
    assert "lockin_time_constant_s" in d.lockin.read_configuration()


def test_stage_moves_and_reads_back():
    sim, d = quiet_sim()
    status = d.arm.set(61.25)
    assert status.done and status.success
    assert d.arm.read()["arm"]["value"] == 61.25
    assert d.arm.read()["arm_setpoint"]["value"] == 61.25
    assert sim.axes["arm"].position() == 61.25
    assert sim.clock.t_s == pytest.approx(61.25 / 10.0)  # simulated travel at 10 deg/s, no wall time


def test_soft_limit_checked_before_motion():
    sim, d = quiet_sim()
    n_before = sim.axes["arm"].n_moves
    with pytest.raises(SoftLimitError, match=r"arm: 2.0 deg is outside the soft limits \[5, 175\] deg; not moved"):
        d.arm.set(2.0)
    with pytest.raises(SoftLimitError):
        d.sample_stage.set(float("nan"))
    assert sim.axes["arm"].n_moves == n_before
    assert isinstance(SoftLimitError("x"), ValueError)


def test_stalled_simulated_axis_fails_status_with_clear_error():
    sim, d = quiet_sim()
    sim.axes["sample"].stall_after_moves = 0
    status = d.sample_stage.set(30.0)
    assert status.done and not status.success
    exc = status.exception()
    assert isinstance(exc, MoveTimeout)
    assert "sample_stage: move to 30 deg not finished" in str(exc)


def test_lockin_reads_calibrated_signal():
    sim, d = quiet_sim(rd=0.3)
    d.sample_stage.set(30.0)
    d.arm.set(30.0 + 40.0)  # theta_r = 40 deg, specular side
    assert d.lockin.trigger().success
    r = d.lockin.read()
    cfg = RigConfig()
    omega = cfg.slit_width_mm * cfg.slit_height_mm / cfg.arm_mm**2
    expected = 1000.0 * 5e-3 * omega * math.cos(math.radians(40.0)) * 0.3 / math.pi
    assert r["lockin_mean_v"]["value"] == pytest.approx(expected, rel=1e-12)
    assert r["lockin_std_v"]["value"] == 0.0 and r["lockin_n"]["value"] == 3


def test_lockin_noise_is_five_percent_near_peak_and_seeded():
    # noise model (rig.sim docstring): sigma = sqrt((0.05 V)^2 + floor^2); a bright point is floor-free
    sim = SimRig(Lambertian(0.3), seed=7, ideal=True)
    d = sim_devices(sim)
    d.arm.set(40.0)
    d.lockin.n_readings.put(400)
    d.lockin.trigger()
    mean, std = d.lockin.mean_v.get(), d.lockin.std_v.get()
    v_true = sim.lockin.true_signal_v()
    assert v_true > 0
    # std of a sample std for n = 400 is ~ sigma / sqrt(2 n) = 3.5 %; 4 sigma -> 14 %
    assert std / v_true == pytest.approx(0.05, rel=0.14)
    assert abs(mean - v_true) < 4 * 0.05 * v_true / math.sqrt(400)
    # the same seed and position give the same readings
    sim2 = SimRig(Lambertian(0.3), seed=7, ideal=True)
    d2 = sim_devices(sim2)
    d2.arm.set(40.0)
    d2.lockin.n_readings.put(400)
    d2.lockin.trigger()
    assert d2.lockin.mean_v.get() == mean


def test_lockin_autorange_climbs_out_of_overload():
    sim, d = quiet_sim(rd=0.3)
    d.arm.set(40.0)
    d.lockin.sensitivity_v.put(2e-9)  # far below the ~1.6e-5 V signal: overloads
    d.lockin.trigger()
    v = d.lockin.mean_v.get()
    assert v == pytest.approx(sim.lockin.true_signal_v(), rel=1e-12)
    assert v <= d.lockin.sensitivity_v.get() < 10 * v  # settled on a range just above the signal


def test_hwp_selects_polarization():
    sim, d = quiet_sim()
    d.hwp.set(0.0)
    assert sim.geometry_now()[3] == pytest.approx(1.0)
    d.hwp.set(45.0)
    assert sim.geometry_now()[3] == pytest.approx(0.0, abs=1e-15)
    d.hwp.set(22.5)
    assert sim.geometry_now()[3] == pytest.approx(0.5)


def test_laser_dip_updates_power_signal_and_recovers():
    import time

    sim, d = quiet_sim()
    seen = []
    d.laser.power_w.subscribe(lambda value, **kw: seen.append(value), run=False)
    sim.laser.dip(fraction=0.1, duration_s=0.05)
    assert d.laser.power_w.get() == pytest.approx(5e-4)
    time.sleep(0.2)
    assert d.laser.power_w.get() == pytest.approx(5e-3)
    assert seen == pytest.approx([5e-4, 5e-3])


def _real(motion="GPIB0::1::INSTR", lockin="GPIB0::8::INSTR", timeout_s=0.05, move_timeout_s=0.2):
    esp = Esp301(open_resource(motion, visa_library=sim_library("esp301.yaml"), timeout_s=timeout_s))
    lia = Sr830(open_resource(lockin, visa_library=sim_library("sr830.yaml"), timeout_s=timeout_s))
    return real_devices(esp, lia, laser_watts_per_volt=0.002, move_timeout_s=move_timeout_s)


def test_real_backend_over_pyvisa_sim():
    d = _real()
    status = d.arm.set(61.2)
    status.wait(2)
    assert d.arm.read()["arm"]["value"] == pytest.approx(61.2)
    d.lockin.settle_factor.put(0.0)
    d.lockin.autorange.put(False)
    st = d.lockin.trigger()
    st.wait(2)
    r = d.lockin.read()
    assert r["lockin_mean_v"]["value"] == pytest.approx(1.25e-3) and r["lockin_std_v"]["value"] == 0.0
    d.laser.trigger().wait(2)
    assert d.laser.power_w.get() == pytest.approx(2.5 * 0.002)
    d.chopper.trigger().wait(2)
    assert d.chopper.frequency_hz.get() == pytest.approx(1000.0)
    d.lockin.time_constant_s.put(0.1)  # forwarded to the instrument (OFLT 8) and read back
    assert d.lockin.time_constant_s.get() == pytest.approx(0.1)
    assert d.lockin._backend.driver.query("OFLT?") == "8"


def test_real_backend_stalled_move_and_mute_lockin():
    d = _real(motion="GPIB0::2::INSTR", lockin="GPIB0::10::INSTR")
    status = d.sample_stage.set(10.0)
    with pytest.raises(Exception):
        status.wait(5)
    assert isinstance(status.exception(), MoveTimeout)
    assert "not finished within 0.2 s" in str(status.exception())
    with pytest.raises(SoftLimitError):
        d.sample_stage.set(120.0)
    d.lockin.settle_factor.put(0.0)
    st = d.lockin.trigger()
    with pytest.raises(Exception):
        st.wait(5)
    assert isinstance(st.exception(), InstrumentTimeout)
