"""Transport shared by the drivers: open a VISA resource, query with a timeout, parse replies.

Every failure becomes one of three exceptions whose message names the instrument, the
resource and the command, so an operator can act on it without a traceback.
"""
from __future__ import annotations

import re
import threading
from pathlib import Path

import pyvisa
from pyvisa import constants

SIM_DIR = Path(__file__).resolve().parent / "sim"


class InstrumentError(RuntimeError):
    """An instrument reported an error or could not be reached."""


class InstrumentTimeout(InstrumentError, TimeoutError):
    """An instrument did not answer (or did not finish) within its timeout."""


class ResponseError(InstrumentError, ValueError):
    """An instrument's reply could not be parsed."""


def one_line(exc: BaseException) -> str:
    """``exc``'s message on one line. pyvisa-sim puts whole tracebacks (as reprs, with ``\\n``) in its
    "Could not parse definitions file." error: keep the text before them and the innermost
    error with its detail lines (the file, line and column of a YAML mistake)."""
    text = str(exc)
    marker = "Traceback (most recent call last):"
    if marker not in text:
        return " ".join(text.split())
    head = text.split(marker, 1)[0].strip().rstrip("'").strip()
    body = text
    for _ in range(4):  # undo the nested reprs
        body = body.replace("\\\\", "\\").replace("\\n", "\n").replace("\\'", "'")
    lines = [ln.strip() for ln in body.splitlines()]
    starts = [k for k, ln in enumerate(lines) if re.match(r"^[\w.]*(Error|Exception|Warning)\b.*:", ln)]
    tail = lines[starts[-1]:] if starts else lines[-1:]
    detail = " ".join(ln for ln in tail if ln and not ln.startswith(("File ", "^", "Traceback", "During handling")))
    detail = detail.strip("'\" ")
    return " ".join(f"{head} {detail}".split())[:400]


def sim_library(yaml_name: str) -> str:
    """The ``visa_library`` string of a bundled pyvisa-sim definition, e.g. ``'esp301.yaml'``."""
    return f"{SIM_DIR / yaml_name}@sim"


def open_resource(resource_name: str, *, visa_library: str = "", timeout_s: float = 2.0,
                  read_termination: str = "\n", write_termination: str = "\n"):
    """Open ``resource_name`` with ``pyvisa.ResourceManager(visa_library)``.

    ``visa_library`` is ``''`` (the system VISA), ``'@py'`` (pyvisa-py) or
    ``'path/to/file.yaml@sim'`` (pyvisa-sim).
    """
    if timeout_s <= 0:
        raise ValueError(f"timeout_s must be > 0, got {timeout_s}")
    try:
        rm = pyvisa.ResourceManager(visa_library)
        res = rm.open_resource(resource_name, read_termination=read_termination,
                               write_termination=write_termination)
    except Exception as exc:  # noqa: BLE001 - pyvisa and its backends raise many kinds; name the resource
        raise InstrumentError(f"cannot open VISA resource {resource_name!r} "
                              f"(library {visa_library or 'default'!r}): {one_line(exc)}") from None
    res.timeout = timeout_s * 1000.0
    return res


class VisaInstrument:
    """Base driver: serialised ``write``/``query`` with timeouts turned into clear errors.

    Parameters
    ----------
    resource : pyvisa resource (or anything with ``write``, ``query``, ``timeout``, ``resource_name``)
    name : str
        Human-readable name used in error messages.
    """

    def __init__(self, resource, name: str):
        self.resource = resource
        self.name = name
        self._lock = threading.RLock()

    @property
    def where(self) -> str:
        return f"{self.name} at {getattr(self.resource, 'resource_name', '?')}"

    def write(self, command: str) -> None:
        with self._lock:
            try:
                self.resource.write(command)
            except pyvisa.errors.VisaIOError as exc:
                raise InstrumentError(f"{self.where}: write {command!r} failed: {exc}") from None

    def query(self, command: str) -> str:
        with self._lock:
            try:
                return self.resource.query(command).strip()
            except pyvisa.errors.VisaIOError as exc:
                if exc.error_code == constants.StatusCode.error_timeout:
                    timeout_s = (self.resource.timeout or 0) / 1000.0
                    raise InstrumentTimeout(
                        f"{self.where}: no reply to {command!r} within {timeout_s:g} s") from None
                raise InstrumentError(f"{self.where}: query {command!r} failed: {exc}") from None

    def query_float(self, command: str) -> float:
        return parse_float(self.query(command), self.where, command)

    def query_int(self, command: str) -> int:
        reply = self.query(command)
        try:
            return int(reply)
        except ValueError:
            raise ResponseError(f"{self.where}: reply {reply!r} to {command!r} is not an integer") from None

    def close(self) -> None:
        with self._lock:
            self.resource.close()


def parse_float(reply: str, where: str, command: str) -> float:
    try:
        return float(reply)
    except ValueError:
        raise ResponseError(f"{where}: reply {reply!r} to {command!r} is not a number") from None


def parse_floats(reply: str, n: int, where: str, command: str) -> list[float]:
    parts = reply.split(",")
    if len(parts) != n:
        raise ResponseError(f"{where}: reply {reply!r} to {command!r}: expected {n} comma-separated numbers")
    return [parse_float(p, where, command) for p in parts]
