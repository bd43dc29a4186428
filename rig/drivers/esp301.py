"""Newport ESP301-style three-axis motion controller (sample stage, detector arm, half-wave plate).

Command set (ESP301 user's manual, section 3): ``xxPAnn`` move absolute, ``xxTP?`` actual
position, ``xxMD?`` motion done (1 = stopped), ``xxVAnn`` / ``xxVA?`` velocity, ``xxST`` stop,
``TB?`` oldest error as ``code, timestamp, message`` (code 0 = no error). Set commands are not
acknowledged; only queries reply.

:class:`Esp301Axis` adapts one axis to the devices' ``AxisBackend`` (:mod:`rig.devices`).
"""
from __future__ import annotations

import time

from rig.drivers.visa import InstrumentError, InstrumentTimeout, ResponseError, VisaInstrument

AXES = (1, 2, 3)


class Esp301(VisaInstrument):
    """Driver for one ESP301 controller. Positions in the axis' user unit (deg for rotary stages)."""

    def __init__(self, resource, name: str = "ESP301"):
        super().__init__(resource, name)

    @staticmethod
    def _axis(axis: int) -> int:
        if axis not in AXES:
            raise ValueError(f"axis must be one of {AXES}, got {axis!r}")
        return axis

    @staticmethod
    def format_move(axis: int, position: float) -> str:
        """``'1PA30.0500'``: move axis 1 to 30.05 (4 decimals, the stage's 0.0001 deg resolution)."""
        return f"{Esp301._axis(axis)}PA{float(position):.4f}"

    def move_absolute(self, axis: int, position: float) -> None:
        self.write(self.format_move(axis, position))

    def position(self, axis: int) -> float:
        return self.query_float(f"{self._axis(axis)}TP?")

    def motion_done(self, axis: int) -> bool:
        reply = self.query(f"{self._axis(axis)}MD?")
        if reply not in ("0", "1"):
            raise ResponseError(f"{self.where}: reply {reply!r} to '{axis}MD?' is not 0 or 1")
        return reply == "1"

    def set_velocity(self, axis: int, velocity: float) -> None:
        if not velocity > 0:
            raise ValueError(f"velocity must be > 0, got {velocity}")
        self.write(f"{self._axis(axis)}VA{float(velocity):.4f}")

    def velocity(self, axis: int) -> float:
        return self.query_float(f"{self._axis(axis)}VA?")

    def stop(self, axis: int) -> None:
        self.write(f"{self._axis(axis)}ST")

    def error(self) -> tuple[int, str]:
        """Oldest error in the controller's buffer: ``(code, message)``; ``(0, ...)`` = none."""
        reply = self.query("TB?")
        parts = [p.strip() for p in reply.split(",", 2)]
        if len(parts) != 3:
            raise ResponseError(f"{self.where}: reply {reply!r} to 'TB?' is not 'code, time, message'")
        try:
            code = int(parts[0])
        except ValueError:
            raise ResponseError(f"{self.where}: reply {reply!r} to 'TB?' has no integer code") from None
        return code, parts[2]

    def check_error(self) -> None:
        code, message = self.error()
        if code != 0:
            raise InstrumentError(f"{self.where}: controller error {code}: {message}")

    def wait_motion_done(self, axis: int, timeout_s: float, poll_s: float = 0.05, sleep=time.sleep) -> float:
        """Poll ``MD?`` until the axis stops; on timeout send ``ST`` and raise InstrumentTimeout.

        Returns the final position.
        """
        deadline = time.monotonic() + timeout_s
        while not self.motion_done(axis):
            if time.monotonic() > deadline:
                self.stop(axis)
                raise InstrumentTimeout(
                    f"{self.where}: axis {axis} still moving after {timeout_s:g} s (stalled?); sent {axis}ST")
            sleep(poll_s)
        return self.position(axis)


class Esp301Axis:
    """AxisBackend over one axis of an :class:`Esp301`."""

    synchronous = False

    def __init__(self, driver, axis: int):
        self.driver = driver
        self.axis = axis

    def move(self, position_deg):
        self.driver.move_absolute(self.axis, position_deg)

    def position(self):
        return self.driver.position(self.axis)

    def done(self):
        return self.driver.motion_done(self.axis)

    def stop(self):
        self.driver.stop(self.axis)

    def sleep(self, seconds):
        time.sleep(seconds)
