"""bluesky plans for the reflectometer: generators of messages, no device calls.

Points
------
A point is ``(theta_i_deg, polarization, theta_r_deg, phi_r_deg)``: the CSV row's key
(CONTRACTS §2). The sample stage goes to ``theta_i``; the arm, measured from the reversed
incoming beam, to ``theta_i + theta_r`` on the specular side (``phi_r = 0``) or
``theta_i - theta_r`` on the backscatter side (``phi_r = 180``); the half-wave plate to
``HWP_DEG[polarization]`` (0 deg = s, 45 deg = p).

The paper plan
--------------
The seed paper's grid lives in :mod:`rig.points` (the project's one paper plan), with the plans
of rig.synth's synthetic scans as arrays.

Custom plans (PLAN.json)
------------------------
::

    {"name": "my-plan", "n_readings": 3, "polarizations": ["s", "p"], "signature": false,
     "incidence": [
        {"theta_i_deg": 20, "theta_r_deg": [0, 10, 19.5, 20, 20.5, 30]},
        {"theta_i_deg": 45, "grid": "paper"},
        {"theta_i_deg": 60, "theta_r_deg": [20, 40], "phi_r_deg": 180, "polarizations": ["s"]}]}

Only ``incidence`` is required; each entry needs ``theta_i_deg`` and one of ``theta_r_deg``
(a list) or ``grid: "paper"``. ``phi_r_deg`` is 0 (default) or 180 (in-plane rig). Unknown
keys are errors. Points are measured polarization by polarization (fewer HWP moves), in the
file's order within each.

The signature plan is the same scan with no sample mounted (Cady 1989; PHYSICS §4): it
measures the instrument's own stray light in BRDF units at every point of the grid.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from bluesky import plan_stubs as bps
from bluesky import preprocessors as bpp
from bluesky.utils import Msg

from rig.devices import ReadingsInterrupted
from rig.points import (PAPER_N_READINGS, PAPER_POLARIZATIONS, PAPER_THETA_I_DEG, PAPER_ZONES_DEG,  # noqa: F401
                        THETA_R_MAX_DEG, WING_STEP_DEG, Point, paper_points, paper_theta_r_deg, point_key)

HWP_DEG = {"s": 0.0, "p": 45.0}


class PlanError(ValueError):
    """A plan file or point list is invalid; the message names the file and the entry."""


def arm_deg(point: Point) -> float:
    """Arm angle (deg from the reversed beam) that views ``point``."""
    if point.phi_r_deg % 360.0 == 0.0:
        return point.theta_i_deg + point.theta_r_deg
    return point.theta_i_deg - point.theta_r_deg


@dataclass(frozen=True)
class PlanSpec:
    """A plan read from PLAN.json (or the built-in paper plan)."""

    name: str
    points: tuple
    n_readings: int = PAPER_N_READINGS
    signature: bool = False


def paper_plan_spec() -> PlanSpec:
    return PlanSpec(name="paper", points=tuple(paper_points()), n_readings=PAPER_N_READINGS)


MAX_N_READINGS = 1000  # readings per point; 1e9 never finished a point
_TOP_KEYS = {"name", "n_readings", "polarizations", "signature", "incidence"}
_ENTRY_KEYS = {"theta_i_deg", "theta_r_deg", "grid", "phi_r_deg", "polarizations"}


def _num(value, where, lo=None, hi=None):
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise PlanError(f"{where}: expected a finite number, got {value!r}")
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        raise PlanError(f"{where}: {value!r} outside [{lo:g}, {hi:g}]")
    return float(value)


def _pols(value, where):
    if isinstance(value, list) and "u" in value:  # the scan CSV has 'u'; the rig's beam leaves the PBS polarized
        raise PlanError(f"{where}: 'u' cannot be set on the rig (its PBS passes s or p only); scan s and p: "
                        f"their mean is the unpolarized BRDF")
    if not isinstance(value, list) or not value or any(p not in ("s", "p") for p in value):
        raise PlanError(f"{where}: expected a non-empty list of 's'/'p', got {value!r}")
    return tuple(value)


def plan_spec_from_dict(data, where: str = "plan") -> PlanSpec:
    """Validate a PLAN.json dict (module docstring) and expand it to points."""
    if not isinstance(data, dict):
        raise PlanError(f"{where}: a plan must be a JSON object")
    unknown = sorted(set(data) - _TOP_KEYS)
    if unknown:
        raise PlanError(f"{where}: unknown key(s) {', '.join(unknown)}; allowed: {', '.join(sorted(_TOP_KEYS))}")
    name = data.get("name", "custom")
    if not isinstance(name, str):
        raise PlanError(f"{where}: 'name' must be a string")
    n_readings = data.get("n_readings", PAPER_N_READINGS)
    if isinstance(n_readings, bool) or not isinstance(n_readings, int) or n_readings < 1:
        raise PlanError(f"{where}: 'n_readings' must be an integer >= 1, got {n_readings!r}")
    if n_readings > MAX_N_READINGS:
        raise PlanError(f"{where}: 'n_readings' = {n_readings} is above {MAX_N_READINGS} (each reading waits for the "
                        f"lock-in to settle, several time constants: a point would take hours); average more "
                        f"points or use a longer time constant")
    signature = data.get("signature", False)
    if not isinstance(signature, bool):
        raise PlanError(f"{where}: 'signature' must be true or false")
    pols = _pols(data.get("polarizations", list(PAPER_POLARIZATIONS)), f"{where}: polarizations")
    entries = data.get("incidence")
    if not isinstance(entries, list) or not entries:
        raise PlanError(f"{where}: 'incidence' must be a non-empty list")
    by_pol: dict[str, list] = {p: [] for p in ("s", "p")}
    for i, entry in enumerate(entries):
        here = f"{where}: incidence[{i}]"
        if not isinstance(entry, dict):
            raise PlanError(f"{here}: expected an object")
        unknown = sorted(set(entry) - _ENTRY_KEYS)
        if unknown:
            raise PlanError(f"{here}: unknown key(s) {', '.join(unknown)}; allowed: {', '.join(sorted(_ENTRY_KEYS))}")
        if "theta_i_deg" not in entry:
            raise PlanError(f"{here}: missing 'theta_i_deg'")
        ti = _num(entry["theta_i_deg"], f"{here}.theta_i_deg", 0.0, 89.0)
        phi = _num(entry.get("phi_r_deg", 0.0), f"{here}.phi_r_deg")
        if phi % 360.0 not in (0.0, 180.0):
            raise PlanError(f"{here}.phi_r_deg: the rig scans in the plane of incidence: 0 or 180, got {phi:g}")
        if ("theta_r_deg" in entry) == ("grid" in entry):
            raise PlanError(f"{here}: give exactly one of 'theta_r_deg' (a list) or 'grid'")
        if "grid" in entry:
            if entry["grid"] != "paper":
                raise PlanError(f"{here}.grid: only 'paper' is known, got {entry['grid']!r}")
            trs = paper_theta_r_deg(ti)
            if phi % 360.0 == 180.0:
                raise PlanError(f"{here}: grid 'paper' is on the specular side (phi_r_deg 0)")
        else:
            raw = entry["theta_r_deg"]
            if not isinstance(raw, list) or not raw:
                raise PlanError(f"{here}.theta_r_deg: expected a non-empty list")
            trs = np.array([_num(v, f"{here}.theta_r_deg[{k}]", 0.0, 89.9) for k, v in enumerate(raw)])
        for pol in _pols(entry.get("polarizations", list(pols)), f"{here}.polarizations"):
            by_pol[pol] += [Point(ti, pol, float(tr), phi % 360.0) for tr in trs]
    points = by_pol["s"] + by_pol["p"]
    seen = set()
    for p in points:
        k = point_key(*p)
        if k in seen:
            raise PlanError(f"{where}: point {p.theta_i_deg:g}/{p.polarization}/{p.theta_r_deg:g}/{p.phi_r_deg:g} listed twice")
        seen.add(k)
    return PlanSpec(name=name, points=tuple(points), n_readings=n_readings, signature=signature)


def load_plan(source) -> PlanSpec:
    """``'paper'`` or the path of a PLAN.json file."""
    if str(source) == "paper":
        return paper_plan_spec()
    from atomicio.inputs import InputFileError, read_input_text

    path = Path(source)
    try:
        data = json.loads(read_input_text(path, "plan file"))
    except InputFileError as exc:
        raise PlanError(str(exc)) from None
    except UnicodeDecodeError as exc:
        raise PlanError(f"{path}: plan file is not UTF-8 text ({exc.reason})") from None
    except FileNotFoundError:
        raise PlanError(f"{path}: no such plan file (use 'paper' or a PLAN.json)") from None
    except json.JSONDecodeError as exc:
        raise PlanError(f"{path}, line {exc.lineno}, column {exc.colno}: invalid JSON: {exc.msg}") from None
    return plan_spec_from_dict(data, where=str(path))


def check_points(points, devices) -> None:
    """Raise the stage's SoftLimitError for the first point the rig cannot reach (nothing moves)."""
    d = devices if isinstance(devices, dict) else devices.as_dict()
    for p in points:
        try:
            d["sample_stage"].check_value(p.theta_i_deg)
            d["arm"].check_value(arm_deg(p))
            d["hwp"].check_value(HWP_DEG[p.polarization])
        except ValueError as exc:
            raise type(exc)(f"point theta_i {p.theta_i_deg:g} deg, {p.polarization}, theta_r {p.theta_r_deg:g} deg, "
                            f"phi_r {p.phi_r_deg:g} deg: {exc}") from None


class StopReason:
    """Why a run ended early, for its stop document.

    bluesky's ``run_wrapper`` closes an aborted run without the reason given to
    ``RE.abort(reason)``; :func:`brdf_scan` closes it with :attr:`text` instead. The caller that
    turns a signal into an abort (``rig.run.run_scan``) sets the text first; when nobody did,
    the stop document still says what happened.
    """

    def __init__(self, text: str = ""):
        self.text = text

    def for_abort(self) -> str:
        return self.text or "aborted (RE.abort after a pause: Ctrl-C, SIGTERM or the operator)"


class ScanFault(RuntimeError):
    """A device failed during a point; ``cause`` is the device's own error (MoveTimeout,
    InstrumentTimeout, ReferenceUnlocked, LockinOverload, SoftLimitError ...)."""

    def __init__(self, cause: BaseException):
        self.cause = cause
        super().__init__(f"{type(cause).__name__}: {cause}")


def device_error(exc: BaseException) -> BaseException:
    """The device error behind a bluesky ``FailedStatus`` (or ``exc`` itself)."""
    from bluesky.utils import FailedStatus

    def from_status(status):
        for part in (getattr(status, "left", None), getattr(status, "right", None)):  # AndStatus
            if part is not None and part.done and not part.success:
                return from_status(part)
        inner = status.exception() if hasattr(status, "exception") else None
        return inner if isinstance(inner, BaseException) and not isinstance(inner, FailedStatus) else None

    if isinstance(exc, FailedStatus) and exc.args:
        inner = from_status(exc.args[0])
        if inner is not None:
            return inner
    return exc


def _devices(devices, kwargs) -> dict:
    """The ophyd objects by role, from a RigDevices / mapping and/or keyword arguments."""
    from rig.devices import DEVICE_ROLES, ScanPoint

    found: dict[str, object] = {}
    if devices is not None:
        found.update(devices if isinstance(devices, dict) else devices.as_dict())
    found.update({k: v for k, v in kwargs.items() if v is not None})
    if found.get("point") is None:
        found["point"] = ScanPoint(name="point")
    missing = [r for r in DEVICE_ROLES if found.get(r) is None]
    if missing:
        raise TypeError(f"brdf_scan: missing device(s) {', '.join(missing)}")
    return found


def brdf_scan(devices=None, points=(), *, n_readings: int = PAPER_N_READINGS, md: dict | None = None, skip=(),
              csv_path=None, log_path=None, resume: bool = False, fsync: bool = True,
              laser_nominal_w: float | None = None, suspend_fraction: float = 0.5, resume_fraction: float = 0.9,
              files=None, stop_reason: StopReason | None = None, check_limits: bool = True,
              lockin=None, laser=None, chopper=None, sample_stage=None, arm=None, hwp=None, point=None):
    """Measure ``points`` (a sequence of :class:`Point`), one event per point, and keep the data safe.

    Devices are ophyd objects, given by keyword (``lockin``, ``laser``, ``chopper``,
    ``sample_stage``, ``arm``, ``hwp``; ``point`` optional) or as a ``rig.devices.RigDevices``
    / mapping first argument. Each point: ``checkpoint``; record the nominal point and move stage
    and arm together (``set`` x 3, ``wait``); ``create``; ``trigger`` lock-in, laser and chopper
    (one group), ``wait``; ``read`` each device (one ophyd object per device in the descriptor's
    ``object_keys``, units and precision in its data keys); ``save``. The HWP moves only when
    the polarization changes. Points whose :func:`point_key` is in ``skip`` are left out.

    Data safety travels with the plan, so ``RE(brdf_scan(...))`` in a notebook or a
    queueserver keeps it: with ``csv_path`` the plan subscribes the CONTRACTS §2 CSV writer and
    the ``[name, doc]`` document log (``log_path``, default ``SCAN.log.jsonl``) for its own
    run (``bluesky.preprocessors.subs_wrapper``), skips the points already in the CSV when
    ``resume``, and installs a ``SuspendFloor`` on the laser power (suspend below
    ``suspend_fraction`` of ``laser_nominal_w``, default the power now; resume above
    ``resume_fraction``; the point is re-measured). Every point is checked against the soft
    limits before anything moves. A device fault closes the run with ``exit_status 'fail'``
    and the device's error as ``reason`` (raised as :class:`ScanFault`); an abort closes it with
    ``exit_status 'abort'`` and ``stop_reason`` (:class:`StopReason`).

    ``files`` : a ready ``rig.writer.ScanFiles`` (what ``rig.run.run_scan`` passes) instead of
    ``csv_path``/``log_path``/``resume``/``fsync``. ``check_limits=False`` leaves the soft
    limits to the devices themselves (each ``set`` still refuses before motion).
    """
    from bluesky.suspenders import SuspendFloor
    from bluesky.utils import RunEngineControlException

    if isinstance(devices, (list, tuple)):  # brdf_scan(points, lockin=..., ...)
        devices, points = None, devices
    d = _devices(devices, dict(lockin=lockin, laser=laser, chopper=chopper, sample_stage=sample_stage, arm=arm,
                               hwp=hwp, point=point))
    points = [Point(*p) for p in points]
    if check_limits:
        check_points(points, d)
    if files is None and csv_path is not None:
        from rig.writer import ScanFiles

        files = ScanFiles(csv_path, log_path=log_path, resume=resume, fsync=fsync)
    skip = set(skip) | (files.completed_keys if files is not None else set())
    todo = [p for p in points if point_key(*p) not in skip]
    stop_reason = stop_reason or StopReason()
    detectors = [d["lockin"], d["laser"], d["chopper"]]
    motors = [d["sample_stage"], d["arm"], d["hwp"]]
    readables = [*detectors, d["point"], *motors]
    _md = {"plan_name": "brdf_scan", "plan_type": "generator", "n_readings": int(n_readings),
           "n_points_total": len(points), "n_points_todo": len(todo), "num_points": len(todo),
           "detectors": [obj.name for obj in detectors], "motors": [obj.name for obj in motors],
           "plan_args": {"detectors": [repr(o) for o in detectors], "motors": [repr(o) for o in motors],
                         "n_points": len(points), "n_readings": int(n_readings), "resume": bool(files and files.resume)},
           "hints": {"dimensions": [(["point_theta_r_deg"], "primary")]}}
    _md.update(md or {})
    if files is not None:
        files.check_resume(**{k: _md[k] for k in ("sample", "plan_name") if k in _md})

    def points_plan():
        # Raw Msgs in the per-point loop: the same messages as bps.mv / bps.trigger_and_read,
        # without bluesky's per-stub stack capture, which costs more than the simulated instrument.
        yield from bps.mv(d["lockin"].n_readings, int(n_readings))
        pol = None
        for i, p in enumerate(todo):
            if p.polarization != pol:
                yield from _fail_on_device_error(bps.mv(d["hwp"], HWP_DEG[p.polarization]))
                pol = p.polarization
            yield Msg("checkpoint")
            yield from _fail_on_device_error(one_point(i, p))

    def one_point(i, p):
        group = f"move-{i}"
        yield Msg("set", d["point"], tuple(p), group=group)
        yield Msg("set", d["sample_stage"], p.theta_i_deg, group=group)
        yield Msg("set", d["arm"], arm_deg(p), group=group)
        yield Msg("wait", None, group=group)
        yield Msg("create", None, name="primary")
        group = f"trigger-{i}"
        for obj in detectors:
            yield Msg("trigger", obj, group=group)
        yield Msg("wait", None, group=group)
        for obj in readables:
            yield Msg("read", obj)
        yield Msg("save")

    def run_plan():
        uid = yield from bps.open_run(_md)

        def except_plan(e):
            if isinstance(e, RunEngineControlException):
                reason = stop_reason.for_abort() if e.exit_status == "abort" else ""
                yield from bps.close_run(exit_status=e.exit_status, reason=reason)
            elif isinstance(e, ScanFault) and isinstance(e.cause, ReadingsInterrupted):
                yield from bps.close_run(exit_status="abort", reason=stop_reason.for_abort())
            else:
                yield from bps.close_run(exit_status="fail", reason=str(e))

        yield from bpp.contingency_wrapper(points_plan(), except_plan=except_plan, else_plan=bps.close_run)
        return uid

    plan = bpp.stage_wrapper(run_plan(), readables)
    if files is not None:
        nominal_w = float(laser_nominal_w) if laser_nominal_w is not None else float(d["laser"].power_w.get())
        suspender = SuspendFloor(d["laser"].power_w, suspend_fraction * nominal_w,
                                 resume_thresh=resume_fraction * nominal_w, sleep=0.0)
        plan = bpp.suspend_wrapper(plan, suspender)
        plan = bpp.subs_wrapper(plan, files.callbacks())
    return plan


def _fail_on_device_error(plan):
    """Run ``plan``; a failed device status becomes :class:`ScanFault` naming the device's error."""
    from bluesky.utils import FailedStatus

    try:
        return (yield from plan)
    except FailedStatus as exc:
        raise ScanFault(device_error(exc)) from exc


def paper_scan(devices, *, md=None, skip=()):
    """The seed paper's scan (module docstring)."""
    spec = paper_plan_spec()
    return (yield from brdf_scan(devices, spec.points, n_readings=spec.n_readings,
                                 md={"plan_name": "paper", **(md or {})}, skip=skip))


def signature_scan(devices, points=None, *, n_readings=PAPER_N_READINGS, md=None, skip=()):
    """Instrument-signature scan: the grid measured with no sample mounted."""
    points = paper_points() if points is None else points
    return (yield from brdf_scan(devices, points, n_readings=n_readings,
                                 md={"plan_name": "signature", "sample": "none (instrument signature)", **(md or {})},
                                 skip=skip))
