"""PyVISA drivers against the pyvisa-sim definitions in rig/drivers/sim/.

Expected command strings and replies come from the ESP301 and SR830 manuals' command
syntax (not from the driver): e.g. ``1PA30.0500`` moves axis 1 to 30.05.
"""
import time

import pytest

from rig.drivers import InstrumentError, InstrumentTimeout, ResponseError, open_resource, sim_library
from rig.devices import AxisBackend, LockinBackend
from rig.drivers.esp301 import Esp301, Esp301Axis
from rig.drivers.sr830 import (SENSITIVITY_V, TIME_CONSTANT_S, Sr830, Sr830Chopper, Sr830Laser, Sr830Lockin,
                              sensitivity_index, time_constant_index)


def esp(resource="GPIB0::1::INSTR", timeout_s=0.05):
    return Esp301(open_resource(resource, visa_library=sim_library("esp301.yaml"), timeout_s=timeout_s))


def lockin(resource="GPIB0::8::INSTR", timeout_s=0.05):
    return Sr830(open_resource(resource, visa_library=sim_library("sr830.yaml"), timeout_s=timeout_s))


class Recorder:
    """Stands in for a VISA resource and records what was written."""

    resource_name = "REC::INSTR"
    timeout = 1000

    def __init__(self):
        self.sent = []

    def write(self, command):
        self.sent.append(command)


def test_esp301_command_formatting():
    rec = Recorder()
    drv = Esp301(rec)
    drv.move_absolute(1, 30.05)
    drv.move_absolute(2, -5)
    drv.set_velocity(3, 2.5)
    drv.stop(2)
    assert rec.sent == ["1PA30.0500", "2PA-5.0000", "3VA2.5000", "2ST"]
    with pytest.raises(ValueError, match="axis"):
        drv.move_absolute(4, 1.0)
    with pytest.raises(ValueError, match="velocity"):
        drv.set_velocity(1, 0.0)


def test_esp301_move_readback_and_status():
    drv = esp()
    drv.move_absolute(1, 30.05)
    drv.move_absolute(2, 61.2)
    assert drv.position(1) == pytest.approx(30.05, abs=1e-9)
    assert drv.position(2) == pytest.approx(61.2, abs=1e-9)
    assert drv.motion_done(1) is True
    assert drv.wait_motion_done(1, timeout_s=0.5) == pytest.approx(30.05)
    drv.set_velocity(1, 5.0)
    assert drv.velocity(1) == pytest.approx(5.0)
    assert drv.error() == (0, "NO ERROR DETECTED")
    drv.check_error()


def test_esp301_stalled_axis_times_out_and_is_stopped():
    drv = esp("GPIB0::2::INSTR")
    drv.move_absolute(1, 10.0)
    t0 = time.monotonic()
    with pytest.raises(InstrumentTimeout, match=r"axis 1 still moving after 0.1 s"):
        drv.wait_motion_done(1, timeout_s=0.1, poll_s=0.01)
    assert time.monotonic() - t0 < 1.0
    with pytest.raises(InstrumentError, match="controller error 107: AXIS 1 FOLLOWING ERROR"):
        drv.check_error()


def test_esp301_mute_controller_read_timeout_names_command():
    drv = esp("GPIB0::3::INSTR")
    with pytest.raises(InstrumentTimeout, match=r"ESP301 at GPIB0::3::INSTR: no reply to '1TP\?' within 0.05 s"):
        drv.position(1)


def test_sr830_tables_match_manual():
    # SR830 manual p. 5-6: SENS 0 = 2 nV, 26 = 1 V; OFLT 0 = 10 us, 19 = 30 ks.
    assert len(SENSITIVITY_V) == 27 and SENSITIVITY_V[0] == 2e-9 and SENSITIVITY_V[26] == 1.0
    assert SENSITIVITY_V[17] == 1e-3 and SENSITIVITY_V[9] == 2e-6
    assert len(TIME_CONSTANT_S) == 20 and TIME_CONSTANT_S[0] == 1e-5 and TIME_CONSTANT_S[19] == 3e4
    assert TIME_CONSTANT_S[9] == 0.3
    assert sensitivity_index(1e-3) == 17 and sensitivity_index(1.1e-3) == 18 and sensitivity_index(5.0) == 26
    assert time_constant_index(0.1) == 8 and time_constant_index(0.25) == 9


def test_sr830_reads_parse():
    drv = lockin()
    assert drv.output("x") == pytest.approx(1.25e-3)
    assert drv.output("theta") == pytest.approx(0.0917)
    assert drv.snap("x", "y") == pytest.approx([1.25e-3, 2e-6])
    assert drv.aux_in_v(1) == pytest.approx(2.5)
    assert drv.frequency_hz() == pytest.approx(1000.0)
    assert drv.status_flags() == []
    with pytest.raises(ValueError, match="output must be"):
        drv.output("z")


def test_sr830_settings_round_trip_and_settling():
    drv = lockin()
    drv.sensitivity_v = 3e-3  # next range up: 5 mV, index 19
    assert drv.sensitivity_index == 19 and drv.sensitivity_v == 5e-3
    drv.time_constant_s = 0.03
    assert drv.time_constant_s == 0.03
    # OFSL default 1 (12 dB/oct): 7 time constants to 99 % (SR830 manual p. 3-5)
    assert drv.settle_time_s() == pytest.approx(7 * 0.03)


def test_sr830_overload_and_bad_reply():
    drv = lockin("GPIB0::9::INSTR")
    assert drv.status_flags() == ["input overload", "output overload"]
    with pytest.raises(ResponseError, match=r"reply 'oops' to 'SENS\?' is not an integer"):
        drv.sensitivity_v


def test_sr830_read_timeout():
    drv = lockin("GPIB0::10::INSTR")
    t0 = time.monotonic()
    with pytest.raises(InstrumentTimeout, match=r"SR830 at GPIB0::10::INSTR: no reply to 'SNAP\? 1,2'"):
        drv.snap("x", "y")
    assert time.monotonic() - t0 < 1.0


def test_open_resource_rejects_bad_timeout():
    with pytest.raises(ValueError, match="timeout_s must be > 0"):
        open_resource("GPIB0::1::INSTR", visa_library=sim_library("esp301.yaml"), timeout_s=0)


def _protocol_methods(protocol):
    return {name for name in vars(protocol) if not name.startswith("_")} | set(getattr(protocol, "__annotations__", {}))


def test_esp301_axis_adapter_lives_with_its_driver_and_drives_one_axis():
    """The ESP301's adapter to the devices' AxisBackend (rig/drivers/esp301.py) moves its own axis
    only and reads it back through the pyvisa-sim controller."""
    assert Esp301Axis.__module__ == "rig.drivers.esp301"
    drv = esp()
    axis = Esp301Axis(drv, 2)
    assert _protocol_methods(AxisBackend) <= set(dir(axis))
    assert axis.synchronous is False
    axis_1_before = drv.position(1)  # pyvisa-sim keeps the controller's state across tests
    axis.move(61.2)
    assert axis.done() is True
    assert axis.position() == pytest.approx(61.2, abs=1e-9)
    assert drv.position(1) == axis_1_before  # the other axes did not move


def test_sr830_adapters_live_with_their_driver_and_read_the_lockin():
    """The SR830's adapters (rig/drivers/sr830.py): lock-in output and settings, the laser monitor
    on AUX IN 1 (P = V x watts_per_volt) and the chopper's frequency (the external reference)."""
    for cls in (Sr830Lockin, Sr830Laser, Sr830Chopper):
        assert cls.__module__ == "rig.drivers.sr830"
    drv = lockin()
    lia = Sr830Lockin(drv)
    assert _protocol_methods(LockinBackend) <= set(dir(lia))
    assert lia.output("x") == pytest.approx(1.25e-3)
    lia.sensitivity_v = 3e-3  # the driver picks the next range up
    assert lia.sensitivity_v == 5e-3
    lia.time_constant_s = 0.03
    assert lia.settle_time_s() == pytest.approx(7 * 0.03)
    assert lia.status_flags() == []
    assert Sr830Laser(drv, watts_per_volt=0.002).power_w() == pytest.approx(2.5 * 0.002)
    assert Sr830Laser(drv, watts_per_volt=0.002, channel=2).channel == 2
    assert Sr830Chopper(drv).frequency_hz() == pytest.approx(1000.0)
