"""Data never lost: the document log and the CONTRACTS §2 CSV, written as the scan runs.

:class:`DocumentLog` appends every bluesky document to a JSON-lines file (one ``[name, doc]``
array per line, as suitcase-jsonl writes it), flushed and fsynced as it arrives, so the log is
complete up to the last document even if the process dies.

:class:`CsvScanWriter` turns each event of the ``primary`` stream into one CSV row and
rewrites the whole file atomically (temp file, fsync, ``os.replace``) after every point:
at every instant the file on disk is a complete, valid scan (``materials.scan.read_scan``
reads it) holding every point measured so far. On resume it keeps the existing file's text
and adds rows after it; a point already in the file is never written twice.

Calibration (seed paper section 2, PHYSICS §4): ``BRDF = P_s / (P_i Omega cos theta_r)``
with ``P_s = V / g`` (lock-in volts over the detector gain ``g`` in V/W), ``P_i`` the laser
monitor power and ``Omega = slit_w slit_h / arm^2``; the same factor converts the standard
deviation of the repeated readings.
"""
from __future__ import annotations

import datetime as _dt
import json
import math
from pathlib import Path

import numpy as np

import atomicio
from materials.scan import format_rows, header_text, read_scan
from rig.instrument import RigConfig
from rig.points import point_key


class ResumeError(ValueError):
    """The existing CSV cannot be continued by this scan (names the file and the mismatch)."""


class DocumentLog:
    """Append each document as one ``[name, doc]`` JSON array per line, the form bluesky's own
    tools read (suitcase-jsonl writes it, ``event_model``'s ``NumpyEncoder`` serialises numpy
    values), flushed and (``fsync=True``) fsynced per document (:func:`atomicio.append_json_line`:
    no handle stays open, so there is nothing to close). The file is created at the first document
    (appending: a resumed scan adds its run after the earlier ones) with the user's umask."""

    def __init__(self, path, fsync: bool = True):
        self.path = Path(path)
        self.fsync = fsync

    def __call__(self, name, doc):
        from event_model import NumpyEncoder

        atomicio.append_json_line(self.path, [name, doc], encoder=NumpyEncoder, fsync=self.fsync)


def read_log(path) -> list[tuple[str, dict]]:
    """The ``(name, doc)`` pairs of a document log, in order (also reads the older
    ``{"name": ..., "doc": ...}`` lines, so a log begun before the change can be resumed)."""
    out = []
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            if line.strip():
                rec = json.loads(line)
                if isinstance(rec, dict):
                    rec = (rec["name"], rec["doc"])
                name, doc = rec
                out.append((name, doc))
    return out


def close_dangling_runs(log: "DocumentLog") -> list[str]:
    """Give every run of ``log``'s file that has a start document but no stop document (its process
    was killed: SIGKILL, power cut) the stop document it never got: ``exit_status`` "abort" (no
    error of the scan is known) with a reason saying so, and the count of its events per stream
    (event-model's ``num_events``). Written through ``log`` before a new run starts, so every start
    in the file has its stop. Returns the uids of the runs closed."""
    import time
    import uuid

    if not log.path.is_file() or log.path.stat().st_size == 0:
        return []
    try:
        records = read_log(log.path)
    except (ValueError, KeyError, TypeError) as exc:
        raise ResumeError(f"{log.path}: damaged document log ({type(exc).__name__}: {exc}); "
                          f"move it aside to start a new log") from None
    open_runs, streams = {}, {}
    counts: dict[str, dict[str, int]] = {}  # run uid -> stream name -> events
    for name, doc in records:
        if name == "start":
            open_runs[doc["uid"]] = doc
            counts[doc["uid"]] = {}
        elif name == "stop":
            open_runs.pop(doc.get("run_start"), None)
        elif name == "descriptor":
            streams[doc["uid"]] = (doc.get("run_start"), doc.get("name", "primary"))
        elif name == "event" and doc.get("descriptor") in streams:
            run, stream = streams[doc["descriptor"]]
            if run in counts:
                counts[run][stream] = counts[run].get(stream, 0) + 1
    for uid in open_runs:
        log("stop", {"run_start": uid, "time": time.time(), "uid": str(uuid.uuid4()), "exit_status": "abort",
                     "reason": "the process ended without closing this run (killed); closed when the scan "
                               "was next opened", "num_events": counts.get(uid, {})})
    return list(open_runs)


def brdf_from_reading(mean_v, std_v, power_w, theta_r_deg, gain_v_per_w, solid_angle_sr):
    """(brdf_per_sr, brdf_std_per_sr) = (V, sigma_V) / (g P_i Omega cos theta_r) (module doc)."""
    scale = gain_v_per_w * power_w * solid_angle_sr * math.cos(math.radians(theta_r_deg))
    if not scale > 0:
        return float("nan"), float("nan")
    return mean_v / scale, std_v / scale


def csv_metadata(start: dict) -> dict:
    """The ``# key: value`` lines of a scan from its start document (CONTRACTS §2 keys first)."""
    md = {"sample": str(start.get("sample", "unknown"))}
    md.update({f"rig.{k}": str(v) for k, v in (start.get("rig") or {}).items()})
    md["date"] = _dt.datetime.fromtimestamp(start.get("time", 0), _dt.timezone.utc).isoformat(timespec="seconds")
    for key in ("wavelength_nm", "plan_name", "backend", "seed", "n_readings"):
        if key in start:
            md[key] = str(start[key])
    if "gain_v_per_w" in start:
        md["calibration.gain_v_per_w"] = str(start["gain_v_per_w"])
    md["run_uid"] = str(start.get("uid", ""))
    return md


class CsvScanWriter:
    """bluesky callback writing the CONTRACTS §2 CSV incrementally and atomically.

    Parameters
    ----------
    path : the CSV file.
    resume : continue an existing file (its sample and plan must match the new run's);
        without it an existing non-empty file is an error, so no data is ever overwritten.
    fsync : fsync each rewrite (off only in tests of speed).
    """

    def __init__(self, path, *, resume: bool = False, fsync: bool = True):
        self.path = Path(path)
        self.resume = resume
        self.fsync = fsync
        self._text = None
        self._keys = set()
        self._descriptors: dict[str, str | None] = {}  # descriptor uid -> stream name
        self._start = None
        self.n_written = 0
        self.n_duplicates = 0
        self._existing = None
        if self.path.exists() and self.path.stat().st_size > 0:
            if not resume:
                raise ResumeError(f"{self.path}: already exists; use --resume to continue it or choose another file")
            self._existing = read_scan(self.path, allow_empty=True)  # a scan stopped after its header resumes
            self._text = self.path.read_text(encoding="utf-8")
            if not self._text.endswith("\n"):
                self._text += "\n"
            e = self._existing
            self._keys = {point_key(*k) for k in zip(e.theta_i_deg, e.polarization, e.theta_r_deg, e.phi_r_deg)}

    @property
    def completed_keys(self) -> set:
        """Point keys already in the file (``rig.plans.point_key``)."""
        return set(self._keys)

    def check_resume(self, **expected) -> None:
        """Raise ResumeError if the existing file's metadata differ (e.g. ``sample=``, ``plan_name=``)."""
        if self._existing is None:
            return
        old = self._existing.metadata
        for key, new in expected.items():
            if key in old and old[key] != str(new):
                raise ResumeError(f"{self.path}: cannot resume: file has {key} {old[key]!r}, this scan {str(new)!r}")

    def __call__(self, name, doc):
        getattr(self, name, lambda doc: None)(doc)

    def start(self, doc):
        self._start = doc
        rig = RigConfig.from_metadata({f"rig.{k}": v for k, v in (doc.get("rig") or {}).items()},
                                      where="start document")
        self._omega = rig.solid_angle_sr
        self._gain = float(doc.get("gain_v_per_w", 1.0))
        self._wavelength_nm = float(doc.get("wavelength_nm", rig.wavelength_nm))
        if self._existing is not None:
            self.check_resume(**{k: doc.get(k, "") for k in ("sample", "plan_name")})
        else:
            self._text = header_text(csv_metadata(doc))
            self._commit()

    def descriptor(self, doc):
        self._descriptors[doc["uid"]] = doc.get("name")

    def event(self, doc):
        if self._descriptors.get(doc["descriptor"]) != "primary":
            return
        d = doc["data"]
        key = point_key(d["point_theta_i_deg"], d["point_polarization"], d["point_theta_r_deg"], d["point_phi_r_deg"])
        if key in self._keys:
            self.n_duplicates += 1  # re-measured after a rewind: the log has it, the CSV keeps the first
            return
        brdf, std = brdf_from_reading(d["lockin_mean_v"], d["lockin_std_v"], d["laser_power_w"],
                                      d["point_theta_r_deg"], self._gain, self._omega)
        row = format_rows(wavelength_nm=self._wavelength_nm, polarization=d["point_polarization"],
                          theta_i_deg=d["point_theta_i_deg"], theta_r_deg=d["point_theta_r_deg"],
                          phi_r_deg=d["point_phi_r_deg"], brdf_per_sr=brdf,
                          brdf_std_per_sr=std if np.isfinite(std) else float("nan"),
                          n_repeats=int(d["lockin_n"]))
        self._text += row
        self._commit()
        self._keys.add(key)
        self.n_written += 1

    def _commit(self):
        atomicio.write_text(self.path, self._text, fsync=self.fsync)


def log_path_for(csv_path) -> Path:
    """The document log next to a scan: ``SCAN.csv`` -> ``SCAN.log.jsonl``."""
    p = Path(csv_path)
    return p.with_name(p.stem + ".log.jsonl")


class ScanFiles:
    """The CSV writer and the document log of one scan, as one bundle a plan subscribes
    (``rig.plans.brdf_scan``): the log first, so a document is in the log before the CSV
    reflects it. ``after``: callbacks subscribed after both (they see the files as written)."""

    def __init__(self, csv_path, *, log_path=None, resume: bool = False, fsync: bool = True, after=()):
        self.csv_path = Path(csv_path)
        self.log_path = Path(log_path) if log_path is not None else log_path_for(csv_path)
        self.resume = resume
        self.csv = CsvScanWriter(self.csv_path, resume=resume, fsync=fsync)
        self.log = DocumentLog(self.log_path, fsync=fsync)
        self.after = list(after)
        self.closed_runs = close_dangling_runs(self.log)  # a killed earlier run gets its stop document

    @property
    def completed_keys(self) -> set:
        return self.csv.completed_keys

    def check_resume(self, **expected) -> None:
        self.csv.check_resume(**expected)

    def check_resume_log(self, md: dict, keys) -> None:
        """ResumeError if the last run in the document log that measured into this file was started
        with other ``keys`` than ``md`` (e.g. another --seed, --ideal or --effect list): a resumed
        scan must continue the same measurement (keys absent from either side are not compared)."""
        if not self.log_path.is_file():
            return
        try:
            starts = [doc for name, doc in read_log(self.log_path) if name == "start"]
        except (ValueError, KeyError, TypeError) as exc:
            raise ResumeError(f"{self.log_path}: damaged document log ({type(exc).__name__}: {exc})") from None
        if not starts:
            return
        first = starts[-1]
        for key in keys:
            if key in first and key in md and json.dumps(first[key], sort_keys=True) != json.dumps(md[key], sort_keys=True):
                raise ResumeError(f"{self.csv_path}: cannot resume: it was measured with {key} {first[key]!r}, "
                                  f"this scan has {md[key]!r} (log {self.log_path.name})")

    def callbacks(self) -> list:
        return [self.log, self.csv, *self.after]
