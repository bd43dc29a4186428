"""ophyd devices of the reflectometer, over a real (PyVISA) or simulated backend.

| device | class | read fields | backend (real) |
|---|---|---|---|
| sample stage | :class:`RotaryStage` | ``<name>`` (readback, deg), ``<name>_setpoint`` | ESP301 axis 1 |
| detector arm | :class:`RotaryStage` | same | ESP301 axis 2 |
| half-wave plate | :class:`RotaryStage` | same (0 deg = s, 45 deg = p) | ESP301 axis 3 |
| laser | :class:`Laser` | ``laser_power_w`` | SR830 AUX IN 1 x watts per volt |
| chopper | :class:`Chopper` | ``chopper_frequency_hz`` | SR830 ``FREQ?`` (external reference) |
| lock-in | :class:`LockIn` | ``lockin_mean_v``, ``lockin_std_v``, ``lockin_n`` | SR830 ``OUTP? 1`` |

A backend is any object with the methods the device calls (see :class:`AxisBackend`,
:class:`LockinBackend`); :mod:`rig.sim` provides simulated ones; each PyVISA driver in :mod:`rig.drivers`
carries its own adapter (``Esp301Axis``, ``Sr830Lockin``, ``Sr830Laser``, ``Sr830Chopper``), which
:func:`real_devices` assembles. Backends with ``synchronous = True`` (the simulation) complete moves and readings in
the calling thread, in simulated time; the others run in a worker thread.

Soft limits are checked in ``set`` before any command is sent (:class:`SoftLimitError`); a
move that does not finish within ``timeout_s`` fails its status with :class:`MoveTimeout`;
a lock-in that does not answer fails the trigger with the driver's ``InstrumentTimeout``.
"""
from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from ophyd import Component as Cpt
from ophyd import Device, Kind, Signal
from ophyd.status import DeviceStatus
from ophyd.utils import LimitError

from rig.drivers.esp301 import Esp301Axis
from rig.drivers.sr830 import (OVERLOAD_BITS, REFERENCE_UNLOCK, SENSITIVITY_V, Sr830Chopper, Sr830Laser,
                              Sr830Lockin)

log = logging.getLogger(__name__)


class SoftLimitError(LimitError):
    """A requested position is outside a device's soft limits (nothing was moved)."""


class MoveTimeout(TimeoutError):
    """A move did not finish in time (stalled axis); the axis was told to stop."""


class ReferenceUnlocked(RuntimeError):
    """The lock-in lost its reference (SR830 LIAS? bit 3) and did not lock again in time."""


class LockinOverload(RuntimeError):
    """The lock-in overloaded (LIAS? bits 0-2) and could not range out of it."""


class ReadingsInterrupted(RuntimeError):
    """A point's readings were stopped by SIGINT/SIGTERM (:meth:`LockIn.halt_readings`); the point is
    not saved, the points before it are, and ``--resume`` measures it again."""


class Quantity(Signal):
    """A soft ophyd Signal whose ``describe()`` carries ``units`` and ``precision`` (decimal
    places), as an EPICS signal's does, so every event descriptor says what its numbers mean."""

    def __init__(self, *args, units: str = "", precision: int | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self.units = units
        self.precision = precision

    def describe(self):
        desc = super().describe()
        entry = desc[self.name]
        if self.units:
            entry["units"] = self.units
        if self.precision is not None:
            entry["precision"] = int(self.precision)
        return desc


class AxisBackend(Protocol):
    def move(self, position_deg: float) -> None: ...
    def position(self) -> float: ...
    def done(self) -> bool: ...
    def stop(self) -> None: ...
    def sleep(self, seconds: float) -> None: ...


class LockinBackend(Protocol):
    sensitivity_v: float
    time_constant_s: float
    def output(self, which: str = "x") -> float: ...
    def settle_time_s(self) -> float: ...
    def status_flags(self) -> list[str]: ...
    def sleep(self, seconds: float) -> None: ...


def _run(backend, device, work) -> DeviceStatus:
    """Run ``work()`` (returns nothing, may raise) and return a status that reports it."""
    status = DeviceStatus(device)

    def target():
        try:
            work()
        except Exception as exc:  # noqa: BLE001 - reported through the status
            status.set_exception(exc)
        else:
            status.set_finished()

    if getattr(backend, "synchronous", False):
        target()
    else:
        threading.Thread(target=target, daemon=True, name=f"{device.name}-worker").start()
    return status


class RotaryStage(Device):
    """A rotation axis as a bluesky Movable/Readable. Positions in degrees.

    Parameters
    ----------
    backend : AxisBackend
    limits_deg : (low, high) soft limits, checked before motion.
    timeout_s : time allowed for one move; a stalled move fails with MoveTimeout.
    poll_s : motion-done polling interval (real backends).
    """

    readback = Cpt(Quantity, value=0.0, kind=Kind.hinted, units="deg", precision=4)
    setpoint = Cpt(Quantity, value=0.0, kind=Kind.normal, units="deg", precision=4)

    def __init__(self, prefix="", *, backend, limits_deg=(-170.0, 170.0), timeout_s=30.0, poll_s=0.02, name, **kwargs):
        super().__init__(prefix, name=name, **kwargs)
        low, high = (float(v) for v in limits_deg)
        if not low < high:
            raise ValueError(f"{name}: limits_deg must be (low, high) with low < high, got {limits_deg}")
        self._backend = backend
        self._limits = (low, high)
        self.timeout_s = float(timeout_s)
        self.poll_s = float(poll_s)
        self.readback.name = name
        pos = backend.position()
        self.readback.put(pos)
        self.setpoint.put(pos)

    @property
    def limits(self):
        return self._limits

    @property
    def position(self) -> float:
        return self.readback.get()

    def check_value(self, value):
        low, high = self._limits
        if not (np.isfinite(value) and low <= value <= high):
            raise SoftLimitError(f"{self.name}: {value} deg is outside the soft limits [{low:g}, {high:g}] deg; not moved")

    def set(self, value, **kwargs):
        value = float(value)
        self.check_value(value)  # before any command reaches the controller
        self.setpoint.put(value)
        backend = self._backend

        def work():
            backend.move(value)
            deadline = time.monotonic() + self.timeout_s
            while not backend.done():
                if getattr(backend, "synchronous", False) or time.monotonic() > deadline:
                    backend.stop()
                    self.readback.put(backend.position())
                    raise MoveTimeout(f"{self.name}: move to {value:g} deg not finished within "
                                      f"{self.timeout_s:g} s (stalled at {backend.position():g} deg); stopped")
                time.sleep(self.poll_s)
            self.readback.put(backend.position())

        return _run(backend, self, work)

    def stop(self, *, success=False):
        self._backend.stop()


class _Backed(Quantity):
    """A configuration signal forwarded to an attribute of the parent's backend."""

    def __init__(self, *args, attr, **kwargs):
        self._attr = attr
        super().__init__(*args, **kwargs)

    def get(self, **kwargs):
        parent = self.parent
        if parent is not None and getattr(parent, "_backend", None) is not None:
            self._readback = getattr(parent._backend, self._attr)
        return super().get(**kwargs)

    def put(self, value, **kwargs):
        parent = self.parent
        if parent is not None and getattr(parent, "_backend", None) is not None:
            setattr(parent._backend, self._attr, value)
            value = getattr(parent._backend, self._attr)
        super().put(value, **kwargs)


class LockIn(Device):
    """Lock-in amplifier: one trigger takes ``n_readings`` readings, each after settling.

    Read fields: ``mean_v``, ``std_v`` (sample standard deviation, ddof = 1), ``n``.
    With ``autorange`` on, an overload moves to the next range up and a reading below 10 % of
    full scale to the next range down (then settles and reads again), so one scan can span the
    six decades of a black coating's BRDF.
    """

    mean_v = Cpt(Quantity, value=np.nan, kind=Kind.hinted, units="V", precision=9)
    std_v = Cpt(Quantity, value=np.nan, kind=Kind.normal, units="V", precision=9)
    n = Cpt(Signal, value=0, kind=Kind.normal)
    #: readings discarded for a reference unlock (then waited for) in the last trigger
    discarded = Cpt(Signal, value=0, kind=Kind.normal)
    sensitivity_v = Cpt(_Backed, attr="sensitivity_v", kind=Kind.config, units="V", precision=9)
    time_constant_s = Cpt(_Backed, attr="time_constant_s", kind=Kind.config, units="s", precision=5)
    n_readings = Cpt(Signal, value=3, kind=Kind.config)
    settle_factor = Cpt(Signal, value=1.0, kind=Kind.config)
    autorange = Cpt(Signal, value=True, kind=Kind.config)
    #: how long a lost reference may take to lock again before the trigger fails
    relock_timeout_s = Cpt(Quantity, value=10.0, kind=Kind.config, units="s", precision=1)

    def __init__(self, prefix="", *, backend, name, **kwargs):
        self._backend = backend
        self._discarded = 0
        self._halt = threading.Event()
        super().__init__(prefix, name=name, **kwargs)

    def halt_readings(self) -> None:
        """Stop the readings of the point being measured before its next reading (a signal handler may
        call it: it only sets an event). A point of 1000 readings at several time constants each would
        otherwise hold Ctrl-C for minutes."""
        self._halt.set()

    def allow_readings(self) -> None:
        self._halt.clear()

    def _read_one(self) -> float:
        """One reading after settling. A reference unlock discards it and waits for the lock
        (:meth:`_wait_for_lock`); an overload moves one range up (autorange) or fails the
        trigger with :class:`LockinOverload`; with autorange a reading under 10 % of full scale
        moves one range down. Every retry reads again after settling."""
        b = self._backend
        for _ in range(2 * len(SENSITIVITY_V)):
            b.sleep(self.settle_factor.get() * b.settle_time_s())
            v = b.output("x")
            flags = set(b.status_flags())
            if REFERENCE_UNLOCK in flags:
                self._discarded += 1
                self._retry()
                self._wait_for_lock()
                continue
            over = sorted(flags & set(OVERLOAD_BITS.values()))
            autorange = bool(self.autorange.get())
            if over and not autorange:
                raise LockinOverload(f"{self.name}: {', '.join(over)} (LIAS?) with autorange off; "
                                     f"the reading is not used")
            if not autorange:
                return v
            idx = int(np.searchsorted(np.asarray(SENSITIVITY_V), b.sensitivity_v * (1 - 1e-9)))
            if over:
                if idx >= len(SENSITIVITY_V) - 1:
                    raise LockinOverload(f"{self.name}: {', '.join(over)} (LIAS?) on the largest range "
                                         f"({SENSITIVITY_V[-1]:g} V); the reading is not used")
                b.sensitivity_v = SENSITIVITY_V[idx + 1]
            elif abs(v) < 0.1 * SENSITIVITY_V[idx] and idx > 0 and abs(v) < 0.5 * SENSITIVITY_V[idx - 1]:
                b.sensitivity_v = SENSITIVITY_V[idx - 1]
            else:
                return v
            self._retry()
        raise LockinOverload(f"{self.name}: no stable range after {2 * len(SENSITIVITY_V)} tries")

    def _retry(self):
        if hasattr(self._backend, "discard_reading"):
            self._backend.discard_reading()

    def _wait_for_lock(self):
        """The reference is lost (LIAS? bit 3): poll the status every settling time until a
        poll finds it locked, or fail after ``relock_timeout_s`` with :class:`ReferenceUnlocked`."""
        b = self._backend
        timeout_s = float(self.relock_timeout_s.get())
        log.warning("%s: reference unlocked (LIAS? bit 3); reading discarded, waiting up to %g s for the lock",
                    self.name, timeout_s)
        waited = 0.0
        step = max(b.settle_time_s(), 0.05)
        while waited <= timeout_s:
            b.sleep(step)
            waited += step
            if REFERENCE_UNLOCK not in set(b.status_flags()):
                return
        raise ReferenceUnlocked(f"{self.name}: reference unlocked (LIAS? bit 3: chopper stopped or its reference "
                                f"lost) for more than {timeout_s:g} s; readings while unlocked are discarded")

    def trigger(self):
        n = int(self.n_readings.get())
        if n < 1:
            raise ValueError(f"{self.name}: n_readings must be >= 1, got {n}")

        def work():
            if hasattr(self._backend, "start_acquisition"):
                self._backend.start_acquisition()
            self._discarded = 0
            values = np.empty(n)
            for k in range(n):
                if self._halt.is_set():
                    raise ReadingsInterrupted(f"{self.name}: readings stopped after {k} of {n} (interrupted)")
                values[k] = self._read_one()
            self.mean_v.put(float(values.mean()))
            self.std_v.put(float(values.std(ddof=1)) if n > 1 else float("nan"))
            self.n.put(n)
            self.discarded.put(self._discarded)

        return _run(self._backend, self, work)


class Laser(Device):
    """Laser with a power monitor. ``power_w`` is refreshed on trigger and, for suspenders, by a
    backend listener (simulation) or a polling thread started by :meth:`start_monitor` (real)."""

    power_w = Cpt(Quantity, value=np.nan, kind=Kind.hinted, units="W", precision=7)

    def __init__(self, prefix="", *, backend, name, **kwargs):
        super().__init__(prefix, name=name, **kwargs)
        self._backend = backend
        self._monitor = None
        self._stop_monitor = threading.Event()
        self.power_w.put(backend.power_w())
        if hasattr(backend, "add_listener"):
            backend.add_listener(lambda p: self.power_w.put(float(p)))

    def trigger(self):
        return _run(self._backend, self, lambda: self.power_w.put(float(self._backend.power_w())))

    def start_monitor(self, interval_s: float = 0.5) -> None:
        if self._monitor is not None:
            return
        self._stop_monitor.clear()

        def loop():
            while not self._stop_monitor.wait(interval_s):
                try:
                    self.power_w.put(float(self._backend.power_w()))
                except Exception:  # noqa: BLE001 - a failed poll is retried; reads report errors
                    pass

        self._monitor = threading.Thread(target=loop, daemon=True, name=f"{self.name}-monitor")
        self._monitor.start()

    def stop_monitor(self) -> None:
        if self._monitor is not None:
            self._stop_monitor.set()
            self._monitor.join(timeout=2.0)
            self._monitor = None


class Chopper(Device):
    """Optical chopper; its frequency is read from the lock-in's reference input."""

    frequency_hz = Cpt(Quantity, value=np.nan, kind=Kind.normal, units="Hz", precision=2)

    def __init__(self, prefix="", *, backend, name, **kwargs):
        super().__init__(prefix, name=name, **kwargs)
        self._backend = backend

    def trigger(self):
        return _run(self._backend, self, lambda: self.frequency_hz.put(float(self._backend.frequency_hz())))


class ScanPoint(Device):
    """The nominal point being measured (what the CSV row records).

    ``set((theta_i_deg, polarization, theta_r_deg, phi_r_deg))`` records it (one message per
    point in the plan); it moves nothing.
    """

    theta_i_deg = Cpt(Quantity, value=np.nan, kind=Kind.normal, units="deg", precision=6)
    theta_r_deg = Cpt(Quantity, value=np.nan, kind=Kind.normal, units="deg", precision=6)
    phi_r_deg = Cpt(Quantity, value=np.nan, kind=Kind.normal, units="deg", precision=6)
    polarization = Cpt(Signal, value="", kind=Kind.normal)

    def set(self, value, **kwargs):
        theta_i_deg, polarization, theta_r_deg, phi_r_deg = value
        self.theta_i_deg.put(float(theta_i_deg))
        self.polarization.put(str(polarization))
        self.theta_r_deg.put(float(theta_r_deg))
        self.phi_r_deg.put(float(phi_r_deg))
        status = DeviceStatus(self)
        status.set_finished()
        return status


@dataclass
class RigDevices:
    """Every device of one reflectometer."""

    sample_stage: RotaryStage
    arm: RotaryStage
    hwp: RotaryStage
    laser: Laser
    chopper: Chopper
    lockin: LockIn
    point: ScanPoint
    backend: object = None

    @property
    def detectors(self):
        """The triggered detectors of every point (the start document's ``detectors``)."""
        return [self.lockin, self.laser, self.chopper]

    @property
    def motors(self):
        """The axes (the start document's ``motors``)."""
        return [self.sample_stage, self.arm, self.hwp]

    def as_dict(self) -> dict:
        """The ophyd objects by role, as :func:`rig.plans.brdf_scan` takes them."""
        return {role: getattr(self, role) for role in DEVICE_ROLES}

    def all(self):
        return [self.sample_stage, self.arm, self.hwp, self.laser, self.chopper, self.lockin, self.point]


#: the roles of a reflectometer's ophyd objects (keyword names of rig.plans.brdf_scan)
DEVICE_ROLES = ("lockin", "laser", "chopper", "sample_stage", "arm", "hwp", "point")

#: Soft limits (deg). The arm cannot go within 5 deg of the incoming beam (its head would block
#: the beam) nor past 175 deg (the stage base).
SAMPLE_LIMITS_DEG = (-89.0, 89.0)
ARM_LIMITS_DEG = (5.0, 175.0)
HWP_LIMITS_DEG = (-360.0, 360.0)


def make_devices(*, axes, laser, chopper, lockin, move_timeout_s=30.0, limits=None, backend=None) -> RigDevices:
    """Build the devices over backends: ``axes`` maps 'sample', 'arm', 'hwp' to axis backends."""
    limits = {"sample": SAMPLE_LIMITS_DEG, "arm": ARM_LIMITS_DEG, "hwp": HWP_LIMITS_DEG, **(limits or {})}
    return RigDevices(
        sample_stage=RotaryStage(backend=axes["sample"], limits_deg=limits["sample"], timeout_s=move_timeout_s, name="sample_stage"),
        arm=RotaryStage(backend=axes["arm"], limits_deg=limits["arm"], timeout_s=move_timeout_s, name="arm"),
        hwp=RotaryStage(backend=axes["hwp"], limits_deg=limits["hwp"], timeout_s=move_timeout_s, name="hwp"),
        laser=Laser(backend=laser, name="laser"),
        chopper=Chopper(backend=chopper, name="chopper"),
        lockin=LockIn(backend=lockin, name="lockin"),
        point=ScanPoint(name="point"),
        backend=backend,
    )


def sim_devices(sim_rig, **kwargs) -> RigDevices:
    """Devices over a :class:`rig.sim.SimRig`."""
    return make_devices(axes=sim_rig.axes, laser=sim_rig.laser, chopper=sim_rig.chopper, lockin=sim_rig.lockin,
                        backend=sim_rig, **kwargs)


# --- real hardware (each driver's adapter lives beside it in rig/drivers/) --------------------
def real_devices(motion, lockin, *, axes=(1, 2, 3), laser_watts_per_volt=0.002, move_timeout_s=30.0,
                 limits=None) -> RigDevices:
    """Devices over real drivers: ``motion`` an Esp301, ``lockin`` an Sr830."""
    sample_axis, arm_axis, hwp_axis = axes
    return make_devices(
        axes={"sample": Esp301Axis(motion, sample_axis), "arm": Esp301Axis(motion, arm_axis),
              "hwp": Esp301Axis(motion, hwp_axis)},
        laser=Sr830Laser(lockin, laser_watts_per_volt), chopper=Sr830Chopper(lockin),
        lockin=Sr830Lockin(lockin), move_timeout_s=move_timeout_s, limits=limits,
    )
