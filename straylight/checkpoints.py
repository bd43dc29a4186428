"""Resumable sweeps: each finished point of a long sweep is written atomically to a folder next to
the output (``DIR/pst.points/point_000012.json``) together with the fingerprint of the run; with
``--resume`` the points found there are read back instead of traced again, so an interrupted sweep
(Ctrl-C, a lost node, a reboot) continues where it stopped and ends with the same numbers (each
point has its own seed and streams, so it does not matter which run traced it). The folder is
removed once the sweep's results are written. Floats go through JSON exactly (``repr``).

Every file is checked before it is trusted: ``run.json`` holds the fingerprint's digest
and the run's parameters in readable form; each point holds its values, its index, the run's digest
and a SHA-256 of the three. A point edited by hand (a PST x1000, a NaN), truncated, or copied from
another run is refused on ``--resume`` with a one-line error naming the file; so is a point or
``run.json`` that is not valid JSON.

``run.json`` also names the layout of the points (:data:`FORMAT`): since the one grid runner
(:mod:`straylight.analyses.grid`) a point holds what that runner keeps (values, rays,
seconds, diagnostics, tag). A folder written by an earlier version is refused on ``--resume`` in one
line that says so."""
from __future__ import annotations

import hashlib
import json
import math
import re
import shutil
from pathlib import Path

import numpy as np

import atomicio

_POINT = "point_{:06d}.json"
_RUN = "run.json"
FORMAT = 2  # 1 (no "format" key): each sweep's own point layout; 2: straylight.analyses.grid.PointRun records


def _plain(obj):
    """A JSON-able stand-in for fingerprint values: arrays by content hash, objects by repr without
    memory addresses."""
    if isinstance(obj, np.ndarray):
        return {"array_sha1": hashlib.sha1(np.ascontiguousarray(obj).tobytes()).hexdigest(), "shape": obj.shape,
                "dtype": str(obj.dtype)}
    if isinstance(obj, (np.floating, np.integer)):
        return obj.item()
    return re.sub(r" at 0x[0-9a-f]+", "", repr(obj))


def fingerprint_digest(fingerprint: dict) -> str:
    """sha256 of everything that decides a sweep's numbers."""
    text = json.dumps(fingerprint, sort_keys=True, default=_plain)
    return hashlib.sha256(text.encode()).hexdigest()


def _parameters(fingerprint: dict) -> dict:
    """The fingerprint as plain JSON (arrays by content hash), for a reader of ``run.json``."""
    return json.loads(json.dumps(fingerprint, sort_keys=True, default=_plain))


def point_checksum(run_digest: str, index: int, values) -> str:
    """SHA-256 of a point's values, its index and its run's digest (values in canonical JSON: floats
    by ``repr``, so any change of any digit changes the sum)."""
    text = json.dumps([run_digest, int(index), values], sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


def read_json(path, what: str = "checkpoint"):
    """``json.loads`` of a file, or a one-line ValueError naming the file (not JSON, not UTF-8, unreadable)."""
    path = Path(path)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError, OSError) as exc:
        raise ValueError(f"--resume: {what} {path} is damaged ({type(exc).__name__}: {exc}); "
                         f"remove it to trace that point again") from None


def _strip_non_finite(obj, where: list, found: list):
    """``obj`` with every non-finite float replaced by None; each one's path and ``repr`` appended to ``found``."""
    if isinstance(obj, dict):
        return {k: _strip_non_finite(v, where + [k], found) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_strip_non_finite(v, where + [i], found) for i, v in enumerate(obj)]
    if isinstance(obj, float) and not math.isfinite(obj):
        found.append([where, repr(obj)])
        return None
    return obj


def _restore_non_finite(values, non_finite, path):
    """Put back the non-finite numbers :func:`_strip_non_finite` took out (``nan``, ``inf``, ``-inf``)."""
    for entry in non_finite or ():
        try:
            where, text = entry
            target = values
            for key in where[:-1]:
                target = target[key]
            if text not in ("nan", "inf", "-inf"):
                raise ValueError(text)
            target[where[-1]] = float(text)
        except (ValueError, TypeError, KeyError, IndexError):
            raise ValueError(f"--resume: {path} has a damaged non_finite list; remove it to trace that point "
                             f"again") from None
    return values


#: Ranges a finished point's numbers must lie in (a checksum proves only that the file was written by
#: this code's recipe, not that its numbers are possible): name -> (low, high), None = unbounded.
VALUE_BOUNDS = {"pst": (0.0, None), "pst_stderr": (0.0, None), "power_w": (0.0, None), "rays": (0, None),
                "seconds": (0.0, None), "dhr": (0.0, 1.0), "transmission": (0.0, 1.0), "pst_normalized": (0.0, None)}


def check_point_values(values, path) -> None:
    """Refuse (one-line ValueError naming the file, the value and its range) a restored point whose
    numbers are impossible: a negative PST, power or ray count, a reflectance above 1."""
    def walk(obj, where):
        if isinstance(obj, dict):
            for k, v in obj.items():
                bounds = VALUE_BOUNDS.get(k)
                if bounds is not None and isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v):
                    low, high = bounds
                    if (low is not None and v < low) or (high is not None and v > high):
                        rng = f">= {low}" if high is None else f"in [{low}, {high}]"
                        raise ValueError(f"--resume: {path}: {'.'.join(map(str, where + [k]))} = {v!r} is impossible "
                                         f"(must be {rng}); remove it to trace that point again")
                walk(v, where + [k])
        elif isinstance(obj, list):
            for i, v in enumerate(obj):
                walk(v, where + [i])
    walk(values, [])


class PointStore:
    """Finished points of one sweep in ``folder``. ``resume=False`` starts afresh, and refuses a folder
    holding an earlier run's finished points (one line naming ``--resume``); ``resume=True`` keeps them, after checking they belong to a run with the same
    fingerprint (else a one-line error naming the folder)."""

    def __init__(self, folder, fingerprint: dict, resume: bool = False):
        self.folder = Path(folder)
        digest = self.digest = fingerprint_digest(fingerprint)
        meta = self.folder / _RUN
        if resume and meta.exists():
            doc = read_json(meta, "run file")
            stored = doc.get("fingerprint_sha256") if isinstance(doc, dict) else None
            if not isinstance(stored, str):
                raise ValueError(f"--resume: {meta} has no fingerprint_sha256; remove {self.folder}")
            if doc.get("format", 1) != FORMAT:
                raise ValueError(f"--resume: {self.folder} was written by another version of straylight (checkpoint "
                                 f"format {doc.get('format', 1)}, this one reads {FORMAT}); remove it or run without "
                                 f"--resume")
            if stored != digest:
                raise ValueError(f"--resume: {self.folder} holds points of a different run (scene, angles, rays, "
                                 f"seed or options changed); remove it or run without --resume")
        elif self.folder.exists():
            old = sorted(self.folder.glob("point_*.json"))
            if old:  # an interrupted run's finished points: never deleted silently
                raise ValueError(f"{self.folder} holds {len(old)} finished point(s) of an earlier, interrupted run; "
                                 f"give --resume to keep them, or remove {self.folder} to start afresh")
        self.folder.mkdir(parents=True, exist_ok=True)
        atomicio.write_json(meta, {"format": FORMAT, "fingerprint_sha256": digest,
                                   "parameters": _parameters(fingerprint)}, indent=1)

    def get(self, index: int):
        """The record of point ``index``, or None if it was not finished. A point whose checksum does
        not match its values (edited, damaged, or of another run) is a ValueError naming the file."""
        path = self.folder / _POINT.format(int(index))
        if not path.exists():
            return None
        doc = read_json(path, "checkpoint point")
        if not isinstance(doc, dict) or not {"values", "sha256", "run_sha256", "index"} <= set(doc):
            raise ValueError(f"--resume: {path} is not a checkpoint point of this version (no checksum); "
                             f"remove it to trace that point again")
        if doc["run_sha256"] != self.digest or doc["index"] != int(index):
            raise ValueError(f"--resume: {path} belongs to another run or point; remove it to trace that point again")
        nf = doc.get("non_finite")
        summed = doc["values"] if not nf else [doc["values"], nf]
        if doc["sha256"] != point_checksum(self.digest, index, summed):
            raise ValueError(f"--resume: {path} was changed after it was written (checksum mismatch: edited or "
                             f"damaged); remove it to trace that point again")
        values = _restore_non_finite(doc["values"], doc.get("non_finite", []), path)
        check_point_values(values, path)
        return values

    def put(self, index: int, record: dict) -> None:
        """Record point ``index`` with its checksum (atomically: a killed run leaves whole points only).
        The file is strict JSON: a non-finite number is ``null`` there, its place and value listed under
        ``non_finite`` (checksummed with the values) so :meth:`get` gives the record back exactly."""
        values = json.loads(json.dumps(record))  # what a reader will get back (tuples as lists...)
        non_finite: list = []
        values = _strip_non_finite(values, [], non_finite)
        doc = {"index": int(index), "run_sha256": self.digest, "values": values,
               "sha256": point_checksum(self.digest, index, values if not non_finite else [values, non_finite])}
        if non_finite:
            doc["non_finite"] = non_finite
        atomicio.write_json(self.folder / _POINT.format(int(index)), doc, indent=None)

    @property
    def n_done(self) -> int:
        return len(list(self.folder.glob("point_*.json")))

    def remove(self) -> None:
        """Delete the folder (the sweep's own results are written)."""
        self.remove_folder(self.folder)

    @staticmethod
    def remove_folder(folder) -> None:
        shutil.rmtree(folder, ignore_errors=True)

