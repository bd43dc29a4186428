"""Resumable sweeps: each finished point of a long sweep is written atomically to a folder next to
the output (``DIR/pst.points/point_000012.json``) together with the fingerprint of the run; with
``--resume`` the points found there are read back instead of traced again, so an interrupted sweep
(Ctrl-C, a lost node, a reboot) continues where it stopped and ends with the same numbers (each
point has its own seed and streams, so it does not matter which run traced it). The folder is
removed once the sweep's results are written. Floats go through JSON exactly (``repr``)."""
from __future__ import annotations

import hashlib
import json
import re
import shutil
from pathlib import Path

import numpy as np

import atomicio

_POINT = "point_{:06d}.json"
_RUN = "run.json"


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


class PointStore:
    """Finished points of one sweep in ``folder``. ``resume=False`` starts afresh (old points are
    removed); ``resume=True`` keeps them, after checking they belong to a run with the same
    fingerprint (else a one-line error naming the folder)."""

    def __init__(self, folder, fingerprint: dict, resume: bool = False):
        self.folder = Path(folder)
        digest = fingerprint_digest(fingerprint)
        meta = self.folder / _RUN
        if resume and meta.exists():
            try:
                stored = json.loads(meta.read_text())["fingerprint_sha256"]
            except (ValueError, KeyError) as exc:
                raise ValueError(f"--resume: {meta} is unreadable ({exc}); remove {self.folder}") from None
            if stored != digest:
                raise ValueError(f"--resume: {self.folder} holds points of a different run (scene, angles, rays, "
                                 f"seed or options changed); remove it or run without --resume")
        elif self.folder.exists():
            for old in self.folder.glob("point_*.json"):
                old.unlink()
        self.folder.mkdir(parents=True, exist_ok=True)
        atomicio.write_text(meta, json.dumps({"fingerprint_sha256": digest}) + "\n")

    def get(self, index: int):
        """The record of point ``index``, or None if it was not finished."""
        path = self.folder / _POINT.format(int(index))
        if not path.exists():
            return None
        return json.loads(path.read_text())

    def put(self, index: int, record: dict) -> None:
        """Record point ``index`` (atomically: a killed run leaves whole points only)."""
        atomicio.write_text(self.folder / _POINT.format(int(index)), json.dumps(record) + "\n")

    @property
    def n_done(self) -> int:
        return len(list(self.folder.glob("point_*.json")))

    def remove(self) -> None:
        """Delete the folder (the sweep's own results are written)."""
        self.remove_folder(self.folder)

    @staticmethod
    def remove_folder(folder) -> None:
        shutil.rmtree(folder, ignore_errors=True)


def restore_grid_point(store, k: int, out: dict, i: int, j: int) -> bool:
    """Fill ``out[key][i, j]`` (a sweep's grid of arrays) from point ``k`` of ``store`` if an
    earlier run finished it; True if so (False without a store)."""
    saved = store.get(k) if store is not None else None
    if saved is None:
        return False
    for key in out:
        out[key][i, j] = saved[key]
    return True


def save_grid_point(store, k: int, out: dict, i: int, j: int) -> None:
    """Record ``out[key][i, j]`` as point ``k`` of ``store`` (nothing without a store)."""
    if store is not None:
        store.put(k, {key: float(out[key][i, j]) for key in out})
