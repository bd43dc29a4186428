"""SRS SR830-style lock-in amplifier.

Command set (SR830 manual, chapter 5): ``OUTP? i`` (1 X, 2 Y, 3 R, 4 theta), ``SNAP? i,j``
(simultaneous values), ``SENS i`` / ``SENS?`` (full-scale index 0..26, 2 nV .. 1 V),
``OFLT i`` / ``OFLT?`` (time constant index 0..19, 10 us .. 30 ks), ``OFSL?`` (filter slope
6/12/18/24 dB/oct), ``OAUX? i`` (aux input i in V; the laser power monitor is on AUX IN 1),
``FREQ?`` (reference frequency: the chopper's, in external reference mode), ``LIAS?`` (status
byte: bit 0 input overload, bit 1 filter overload, bit 2 output overload, bit 3 reference unlock;
the bits latch until read and reading clears them, so :meth:`Sr830.status_flags` reads the byte
once and reports every bit).

Adapters to the devices' backends (:mod:`rig.devices`): :class:`Sr830Lockin` (``LockinBackend``),
:class:`Sr830Laser` (laser power monitor on an AUX input), :class:`Sr830Chopper` (the reference
frequency).
"""
from __future__ import annotations

import time

import numpy as np

from rig.drivers.visa import ResponseError, VisaInstrument, parse_floats

#: Full-scale sensitivity in V (or A) for SENS index 0..26.
SENSITIVITY_V = tuple(float(f"{m}e{e}") for e in range(-9, 0) for m in (2, 5, 10))[:26] + (1.0,)
#: Time constant in s for OFLT index 0..19.
TIME_CONSTANT_S = tuple(float(f"{m}e{e}") for e in range(-5, 5) for m in (1, 3))
#: Time constants to settle to 99 % after a step, for OFSL 0..3 (SR830 manual, p. 3-5).
SETTLE_TC_99 = (5.0, 7.0, 9.0, 10.0)
OUTPUTS = {"x": 1, "y": 2, "r": 3, "theta": 4}
OVERLOAD_BITS = {0: "input overload", 1: "filter overload", 2: "output overload"}
REFERENCE_UNLOCK = "reference unlock"
#: LIAS? bits 0-3 (SR830 manual, "LIA status byte"): the overloads and the reference unlock
STATUS_BITS = {**OVERLOAD_BITS, 3: REFERENCE_UNLOCK}


def sensitivity_index(full_scale_v: float) -> int:
    """Smallest SENS index whose full scale is >= ``full_scale_v`` (the largest if none)."""
    idx = int(np.searchsorted(np.asarray(SENSITIVITY_V), full_scale_v * (1 - 1e-9)))
    return min(idx, len(SENSITIVITY_V) - 1)


def time_constant_index(tc_s: float) -> int:
    """OFLT index of the time constant nearest ``tc_s`` (in log)."""
    if not tc_s > 0:
        raise ValueError(f"time constant must be > 0 s, got {tc_s}")
    return int(np.argmin(np.abs(np.log(np.asarray(TIME_CONSTANT_S) / tc_s))))


class Sr830(VisaInstrument):
    """Driver for one SR830 lock-in amplifier."""

    def __init__(self, resource, name: str = "SR830"):
        super().__init__(resource, name)

    def output(self, which: str = "x") -> float:
        """One output, ``'x'``, ``'y'``, ``'r'`` (V) or ``'theta'`` (deg): ``OUTP? i``."""
        if which not in OUTPUTS:
            raise ValueError(f"output must be one of {sorted(OUTPUTS)}, got {which!r}")
        return self.query_float(f"OUTP? {OUTPUTS[which]}")

    def snap(self, *which: str) -> list[float]:
        """2 to 6 values read at the same instant: ``SNAP? 1,2``."""
        if not 2 <= len(which) <= 6 or any(w not in OUTPUTS for w in which):
            raise ValueError(f"snap needs 2..6 of {sorted(OUTPUTS)}, got {which!r}")
        command = "SNAP? " + ",".join(str(OUTPUTS[w]) for w in which)
        return parse_floats(self.query(command), len(which), self.where, command)

    @property
    def sensitivity_v(self) -> float:
        idx = self.query_int("SENS?")
        if not 0 <= idx < len(SENSITIVITY_V):
            raise ResponseError(f"{self.where}: SENS? index {idx} out of range 0..26")
        return SENSITIVITY_V[idx]

    @sensitivity_v.setter
    def sensitivity_v(self, full_scale_v: float) -> None:
        self.write(f"SENS {sensitivity_index(full_scale_v)}")

    @property
    def sensitivity_index(self) -> int:
        return self.query_int("SENS?")

    @sensitivity_index.setter
    def sensitivity_index(self, idx: int) -> None:
        if not 0 <= idx < len(SENSITIVITY_V):
            raise ValueError(f"sensitivity index must be 0..26, got {idx}")
        self.write(f"SENS {int(idx)}")

    @property
    def time_constant_s(self) -> float:
        idx = self.query_int("OFLT?")
        if not 0 <= idx < len(TIME_CONSTANT_S):
            raise ResponseError(f"{self.where}: OFLT? index {idx} out of range 0..19")
        return TIME_CONSTANT_S[idx]

    @time_constant_s.setter
    def time_constant_s(self, tc_s: float) -> None:
        self.write(f"OFLT {time_constant_index(tc_s)}")

    def settle_time_s(self) -> float:
        """Time to settle to 99 % after a step: N time constants for the current filter slope."""
        slope = self.query_int("OFSL?")
        if not 0 <= slope < 4:
            raise ResponseError(f"{self.where}: OFSL? index {slope} out of range 0..3")
        return SETTLE_TC_99[slope] * self.time_constant_s

    def aux_in_v(self, channel: int = 1) -> float:
        if channel not in (1, 2, 3, 4):
            raise ValueError(f"aux input must be 1..4, got {channel}")
        return self.query_float(f"OAUX? {channel}")

    def frequency_hz(self) -> float:
        return self.query_float("FREQ?")

    def status(self) -> int:
        """The LIA status byte (reading clears it)."""
        return self.query_int("LIAS?")

    def status_flags(self) -> list[str]:
        """Names of the LIAS? bits 0-3 set since the last read (overloads and ``'reference unlock'``);
        empty when none. One query: reading the byte clears it, so every bit is reported here."""
        return flags_from_status_byte(self.status())


def flags_from_status_byte(byte: int) -> list[str]:
    """The :data:`STATUS_BITS` names set in a LIAS? byte, in bit order."""
    return [name for bit, name in STATUS_BITS.items() if int(byte) >> bit & 1]


class Sr830Lockin:
    """LockinBackend over an :class:`Sr830`."""

    synchronous = False

    def __init__(self, driver):
        self.driver = driver

    sensitivity_v = property(lambda self: self.driver.sensitivity_v,
                             lambda self, v: setattr(self.driver, "sensitivity_v", v))
    time_constant_s = property(lambda self: self.driver.time_constant_s,
                               lambda self, v: setattr(self.driver, "time_constant_s", v))

    def output(self, which="x"):
        return self.driver.output(which)

    def settle_time_s(self):
        return self.driver.settle_time_s()

    def status_flags(self):
        return self.driver.status_flags()

    def sleep(self, seconds):
        time.sleep(seconds)


class Sr830Laser:
    """Laser power monitor on the lock-in's AUX IN ``channel``: P = V x watts_per_volt."""

    synchronous = False

    def __init__(self, driver, watts_per_volt: float, channel: int = 1):
        self.driver = driver
        self.watts_per_volt = float(watts_per_volt)
        self.channel = channel

    def power_w(self):
        return self.driver.aux_in_v(self.channel) * self.watts_per_volt


class Sr830Chopper:
    """The chopper's frequency, read as the lock-in's external reference frequency (``FREQ?``)."""

    synchronous = False

    def __init__(self, driver):
        self.driver = driver

    def frequency_hz(self):
        return self.driver.frequency_hz()
