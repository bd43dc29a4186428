"""Run a reflectometer scan end to end: devices, plan, RunEngine, log, CSV, faults.

:func:`run_scan` is what ``straylight rig scan`` calls. It

1. refuses to overwrite an existing scan unless resuming, and on resume skips every point
   already in the CSV (``rig.plans.point_key``);
2. checks every point against the soft limits before anything moves;
3. runs the plan in a bluesky ``RunEngine``; the plan itself subscribes the document log and
   the CSV writer and installs a ``SuspendFloor`` on the laser power (the scan suspends when
   the power falls below ``suspend_fraction`` of nominal and resumes, re-measuring the point,
   when it is back above ``resume_fraction``), so ``RE(plan)`` anywhere keeps them; this adds
   SIGINT/SIGTERM turned into a pause then an abort, so an interrupted run still ends with a
   stop document naming the signal;
4. reports a fault (stalled move, lock-in timeout or overload, reference unlock, soft limit)
   as :class:`ScanFailed` naming the cause and how many points are saved.
"""
from __future__ import annotations

import atexit
import json
import math
import signal
import threading
from dataclasses import dataclass
from pathlib import Path

from rig.devices import ReadingsInterrupted
from rig.instrument import RigConfig
from rig.plans import PlanSpec, ScanFault, StopReason, brdf_scan, device_error
from rig.writer import ScanFiles

DEFAULT_GAIN_V_PER_W = 1000.0
# settings a resumed scan must share with the run that began the file (its start document): they
# decide the numbers of the points still to measure
RESUME_KEYS = ("sample", "plan_name", "backend", "seed", "ideal", "sim_effects", "hardware_config", "wavelength_nm",
               "gain_v_per_w")


class ScanFailed(RuntimeError):
    """A scan stopped on a fault; the message names it and what was saved."""


class HardwareConfigError(ValueError):
    """Bad --hardware configuration file (names the file and key)."""


@dataclass
class ScanOutcome:
    csv_path: Path
    log_path: Path
    exit_status: str  # 'success', 'abort' or 'fail'
    n_points_plan: int
    n_points_in_file: int
    n_measured: int
    reason: str = ""


def check_gain(gain_v_per_w, where: str = "gain_v_per_w") -> float:
    """The detector gain (V/W) as a float: finite and > 0, else a one-line error (a gain of 0 or
    below ran a whole scan of NaN with exit 0)."""
    try:
        g = float(gain_v_per_w)
    except (TypeError, ValueError):
        raise HardwareConfigError(f"{where} must be a number of V/W, got {gain_v_per_w!r}") from None
    if not math.isfinite(g) or g <= 0:
        raise HardwareConfigError(f"{where} must be a finite number > 0 (V/W: the detector's volts per watt), "
                                  f"got {gain_v_per_w!r}")
    return g


def run_scan(devices, spec: PlanSpec, csv_path, *, sample: str, config: RigConfig | None = None,
             md: dict | None = None, resume: bool = False, progress: bool = False, log_path=None,
             gain_v_per_w: float = DEFAULT_GAIN_V_PER_W, suspend_fraction: float = 0.5,
             resume_fraction: float = 0.9, handle_signals: bool = True, fsync: bool = True,
             run_engine=None, callbacks=(), nominal_power_w: float | None = None) -> ScanOutcome:
    """Measure ``spec`` with ``devices`` into ``csv_path`` (CONTRACTS §2) and its document log.

    The plan (``rig.plans.brdf_scan``) carries the CSV, the log and the laser suspender itself;
    this adds what only a program owning the process can: SIGINT/SIGTERM turned into a pause
    then an abort with the signal named in the stop document, a progress bar, the outcome.
    Returns a :class:`ScanOutcome` (``exit_status`` 'abort' after SIGINT/SIGTERM or
    ``run_engine.request_pause``); raises :class:`ScanFailed` on a device fault and
    ``rig.writer.ResumeError`` / ``SoftLimitError`` on bad requests, before anything moves.
    ``callbacks`` are subscribed after the log and the CSV writer (they see the files as
    written for each document). The laser suspender's thresholds are fractions of
    ``nominal_power_w`` (default: the power read when the scan starts).
    """
    from bluesky.utils import RunEngineInterrupted

    check_gain(gain_v_per_w)
    config = config or RigConfig()
    csv_path = Path(csv_path)
    files = ScanFiles(csv_path, log_path=log_path, resume=resume, fsync=fsync, after=callbacks)
    done = files.completed_keys
    rig_md = {k.split(".", 1)[1]: v for k, v in config.to_metadata().items()}  # no dots in document keys
    full_md = {"sample": sample, "rig": rig_md, "wavelength_nm": config.wavelength_nm,
               "gain_v_per_w": float(gain_v_per_w), "plan_name": spec.name, "resumed": bool(resume and done),
               **(md or {})}
    # settings that decide the numbers must be those of the file being continued (a resume with
    # another --seed would mix two noise streams under the first run's header)
    files.check_resume(**{k: full_md[k] for k in ("sample", "plan_name", "backend", "seed") if k in full_md})
    if resume and done:
        files.check_resume_log(full_md, RESUME_KEYS)
    stop_reason = StopReason()
    nominal_w = float(nominal_power_w) if nominal_power_w is not None else devices.laser.power_w.get()
    plan = brdf_scan(devices, spec.points, n_readings=spec.n_readings, md=full_md, files=files,
                     laser_nominal_w=nominal_w, suspend_fraction=suspend_fraction,
                     resume_fraction=resume_fraction, stop_reason=stop_reason)
    real = not getattr(devices.backend, "synchronous", False) and devices.backend is None
    if real:
        devices.laser.start_monitor()
    n_todo = sum(1 for p in spec.points if _key(p) not in done)
    if hasattr(devices.backend, "prefetch"):
        devices.backend.prefetch([p for p in spec.points if _key(p) not in done])

    RE = run_engine if run_engine is not None else session_run_engine()
    if run_engine is None:
        RE.md.clear()  # each scan's documents as from a fresh engine (scan_id 1), as when one was made per scan
    tokens = []
    bar = None
    if progress:
        from straylight.progress import progress_bar

        bar = progress_bar(total=len(spec.points), initial=len(spec.points) - n_todo, unit="pt", desc=spec.name)
        tokens.append(RE.subscribe(lambda name, doc: bar.update(1), "event"))
    interrupted = {}
    old_handlers = {}

    def on_signal(signum, frame):
        interrupted["signal"] = signal.Signals(signum).name
        stop_reason.text = f"interrupted ({interrupted['signal']})"
        # request_pause blocks until the RunEngine's loop thread acknowledges: never call it
        # from that thread or hold the main thread on it (bluesky's SigintHandler does the same)
        threading.Thread(target=_quiet_pause, args=(RE,), daemon=True).start()
        halt = getattr(getattr(devices, "lockin", None), "halt_readings", None)
        if halt is not None:  # a point of many readings stops before its next one
            halt()

    if handle_signals and threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            old_handlers[sig] = signal.signal(sig, on_signal)
    status, reason = "success", ""
    try:
        try:
            RE(plan)
        except RunEngineInterrupted:
            reason = f"interrupted ({interrupted.get('signal', 'pause requested')})"
            stop_reason.text = reason
            RE.abort(reason)
            status = "abort"
        except Exception as exc:  # noqa: BLE001 - a fault; the plan closed the run with 'fail'
            cause = exc.cause if isinstance(exc, ScanFault) else device_error(exc)
            if isinstance(cause, ReadingsInterrupted):  # a signal stopped a point's readings: the plan aborted
                status = "abort"
                reason = stop_reason.text = f"interrupted ({interrupted.get('signal', 'readings halted')})"
            else:
                status, reason = "fail", f"{type(cause).__name__}: {cause}"
    finally:
        allow = getattr(getattr(devices, "lockin", None), "allow_readings", None)
        if allow is not None:
            allow()
        for sig, handler in old_handlers.items():
            signal.signal(sig, handler)
        if real:
            devices.laser.stop_monitor()
        for token in tokens:
            RE.unsubscribe(token)
        if bar is not None:
            bar.close()
    outcome = ScanOutcome(csv_path=csv_path, log_path=files.log_path, exit_status=status,
                          n_points_plan=len(spec.points), n_points_in_file=len(files.completed_keys),
                          n_measured=files.csv.n_written, reason=reason)
    if status == "fail":
        raise ScanFailed(f"{reason}; {outcome.n_points_in_file} of {outcome.n_points_plan} points saved in "
                         f"{csv_path} (log {files.log_path.name}); fix the fault and rerun with --resume")
    return outcome


_SESSION: dict = {}  # {"engine": the RunEngine of this process}, made on first use
_SESSION_LOCK = threading.Lock()


def session_run_engine():
    """The one bluesky ``RunEngine`` of this process, made on first use and stopped at exit.

    A RunEngine runs its event loop on a thread of its own; one made per scan and never stopped
    leaves a thread behind for every scan. This one is shared by every :func:`run_scan` of the
    process that is not given its own ``run_engine``; :func:`stop_session_run_engine` (registered
    with ``atexit``) stops its loop and joins the thread."""
    with _SESSION_LOCK:
        engine = _SESSION.get("engine")
        if engine is None:
            from bluesky import RunEngine

            engine = _SESSION["engine"] = RunEngine({}, context_managers=[])
            if len(_SESSION) == 1:
                _SESSION["atexit"] = True
                atexit.register(stop_session_run_engine)
        return engine


def stop_session_run_engine(timeout_s: float = 5.0) -> None:
    """Stop the session RunEngine's event loop and join its thread (nothing to do if none was made);
    the next :func:`session_run_engine` makes a new one."""
    with _SESSION_LOCK:
        engine = _SESSION.pop("engine", None)
    if engine is not None:
        stop_run_engine(engine, timeout_s)


def stop_run_engine(engine, timeout_s: float = 5.0) -> None:
    """Stop a RunEngine's event loop (it must be idle) and join the thread that runs it."""
    loop, thread = engine.loop, getattr(engine, "_th", None)
    if loop.is_running():
        loop.call_soon_threadsafe(loop.stop)
    if thread is not None:
        thread.join(timeout_s)
    if not loop.is_running() and not loop.is_closed():
        loop.close()


def _quiet_pause(RE):
    try:
        RE.request_pause(defer=False)
    except Exception:  # noqa: BLE001 - the run already ended or is pausing: nothing to pause
        pass


def _key(p):
    from rig.plans import point_key

    return point_key(*p)


# --- building the instrument ---------------------------------------------------------------
def load_sample(sample):
    """A material from a preset name or a MODEL.json path; ``None``/'none' for no sample."""
    if sample is None or str(sample).lower() == "none":
        return None
    from materials.material import load_material

    return load_material(sample)


def sim_instrument(sample, config: RigConfig | None = None, *, seed: int = 0, ideal: bool = False,
                   effects=(), **kwargs):
    """(SimRig, RigDevices) for a sample (material, preset name, path or None)."""
    from rig.devices import sim_devices
    from rig.sim import SimRig

    material = load_sample(sample) if sample is None or isinstance(sample, (str, Path)) else sample
    if config is None:  # the simulated laser runs at the sample model's wavelength (the CSV's wavelength_nm)
        wavelength_nm = getattr(material, "wavelength_nm", None)
        config = RigConfig(wavelength_nm=float(wavelength_nm)) if wavelength_nm else RigConfig()
    sim = SimRig(material, config, seed=seed, ideal=ideal, effects=effects, **kwargs)
    return sim, sim_devices(sim)


def _resolve_library(lib: str, base: Path) -> str:
    if not lib.endswith("@sim"):
        return lib
    path = Path(lib[: -len("@sim")])
    if not path.is_absolute():
        from rig.drivers import SIM_DIR

        for candidate in (base / path, SIM_DIR / path):
            if candidate.exists():
                return f"{candidate}@sim"
        raise HardwareConfigError(f"pyvisa-sim file {path} not found next to the config or in {SIM_DIR}")
    return lib


def load_hardware_config(path) -> dict:
    """Read a --hardware TOML or JSON file (see docs/rig.md)."""
    from atomicio.inputs import InputFileError, read_input_bytes

    path = Path(path)
    try:
        raw = read_input_bytes(path, "hardware config")
    except InputFileError as exc:
        raise HardwareConfigError(str(exc)) from None
    except FileNotFoundError:
        raise HardwareConfigError(f"{path}: no such hardware config") from None
    try:
        if path.suffix.lower() == ".json":
            data = json.loads(raw.decode("utf-8"))
        else:
            import tomllib

            data = tomllib.loads(raw.decode("utf-8"))
    except json.JSONDecodeError as exc:
        raise HardwareConfigError(f"{path}, line {exc.lineno}, column {exc.colno}: {exc.msg}") from None
    except Exception as exc:  # tomllib.TOMLDecodeError carries line/column in its message
        raise HardwareConfigError(f"{path}: {exc}") from None
    allowed = {"visa_library", "gain_v_per_w", "laser_watts_per_volt", "laser_nominal_w", "move_timeout_s",
               "motion", "lockin", "rig"}
    unknown = sorted(set(data) - allowed)
    if unknown:
        raise HardwareConfigError(f"{path}: unknown key(s) {', '.join(unknown)}; allowed: {', '.join(sorted(allowed))}")
    if "gain_v_per_w" in data:
        check_gain(data["gain_v_per_w"], f"{path}: gain_v_per_w")
    for section in ("motion", "lockin"):
        if not isinstance(data.get(section), dict) or "resource" not in data[section]:
            raise HardwareConfigError(f"{path}: [{section}] needs a 'resource' (a VISA resource name)")
    data["_base"] = path.parent
    data["_path"] = str(path)
    return data


def hardware_instrument(hw: dict):
    """(RigConfig, RigDevices, gain_v_per_w) from a loaded hardware config."""
    from rig.devices import real_devices
    from rig.drivers import open_resource
    from rig.drivers.esp301 import Esp301
    from rig.drivers.sr830 import Sr830

    where = hw.get("_path", "hardware config")
    base = Path(hw.get("_base", "."))
    default_lib = hw.get("visa_library", "")
    drivers = {}
    for section, cls in (("motion", Esp301), ("lockin", Sr830)):
        sec = hw[section]
        allowed = {"resource", "visa_library", "timeout_s", "axes", "time_constant_s", "sensitivity_v"}
        unknown = sorted(set(sec) - allowed)
        if unknown:
            raise HardwareConfigError(f"{where}: [{section}] unknown key(s) {', '.join(unknown)}")
        lib = _resolve_library(str(sec.get("visa_library", default_lib)), base)
        res = open_resource(sec["resource"], visa_library=lib, timeout_s=float(sec.get("timeout_s", 2.0)))
        drivers[section] = cls(res)
    lockin = drivers["lockin"]
    assert isinstance(lockin, Sr830)
    if "time_constant_s" in hw["lockin"]:
        lockin.time_constant_s = float(hw["lockin"]["time_constant_s"])
    if "sensitivity_v" in hw["lockin"]:
        lockin.sensitivity_v = float(hw["lockin"]["sensitivity_v"])
    axes = hw["motion"].get("axes", {})
    try:
        config = RigConfig(**hw.get("rig", {}))
    except TypeError as exc:
        raise HardwareConfigError(f"{where}: [rig] {exc}") from None
    devices = real_devices(drivers["motion"], lockin,
                           axes=(int(axes.get("sample", 1)), int(axes.get("arm", 2)), int(axes.get("hwp", 3))),
                           laser_watts_per_volt=float(hw.get("laser_watts_per_volt", 0.002)),
                           move_timeout_s=float(hw.get("move_timeout_s", 30.0)))
    return config, devices, check_gain(hw.get("gain_v_per_w", DEFAULT_GAIN_V_PER_W), f"{where}: gain_v_per_w")
