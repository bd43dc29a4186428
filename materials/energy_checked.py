"""Materials already found energy-conserving, remembered on disk, so a repeat command skips the check.

:meth:`materials.material.Material.check_energy` integrates rho(theta_i) at 90 angles for both
polarizations (~1 s of every command's start-up for the glossy ``z302_sample_b``). A material that
passed leaves a marker file ``<cache>/energy_check/<key>``, key = SHA-256 of its material-file
dict (``Material.to_dict``, floats written exactly) and of the source of the ``materials`` package
(a changed model or quadrature checks again). Only passes are remembered: a material that fails is
checked, and refused, every time. ``STRAYLIGHT_CACHE=off`` turns the memo off (atomicio.cache_dirs).

The marker holds ``{"key", "max_reflectance", "sha256"}``: the largest directional-hemispherical
reflectance the check found and a checksum of both. A marker is believed only if its checksum holds
AND its value is possible (a finite number in [0, 1)): a marker whose checksum was recomputed around
an impossible value (3.14) is ignored and the material checked again. An empty marker (an
older version's) is checked again too.
"""
from __future__ import annotations

import hashlib
import json
from functools import lru_cache
from pathlib import Path

import atomicio
from atomicio.cache_dirs import cache_dir, enabled

PACKAGE_DIR = Path(__file__).resolve().parent


@lru_cache(maxsize=1)
def _code_digest() -> str:
    h = hashlib.sha256()
    for path in sorted(PACKAGE_DIR.rglob("*.py")):
        h.update(path.relative_to(PACKAGE_DIR).as_posix().encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def check_key(material) -> str | None:
    """The memo key of ``material`` (None when the memo is off or the material has no exact dict)."""
    if not enabled():
        return None
    try:
        text = json.dumps(material.to_dict(), sort_keys=True, allow_nan=True)  # a key, not a file
    except (TypeError, ValueError):
        return None
    return hashlib.sha256((_code_digest() + "\n" + text).encode()).hexdigest()


def _marker(key: str) -> Path:
    return cache_dir("energy_check") / key


def _marker_checksum(key: str, max_reflectance: float) -> str:
    return hashlib.sha256(f"{key}\n{max_reflectance!r}".encode()).hexdigest()


def marker_values_possible(doc) -> bool:
    """Is a marker's content a pass this module could have written: its own key, a checksum that holds,
    and a maximum reflectance that is a finite number in [0, 1)?"""
    if not isinstance(doc, dict):
        return False
    key, rho = doc.get("key"), doc.get("max_reflectance")
    if not isinstance(key, str) or isinstance(rho, bool) or not isinstance(rho, (int, float)):
        return False
    if not (0.0 <= float(rho) < 1.0):  # NaN fails both
        return False
    return doc.get("sha256") == _marker_checksum(key, float(rho))


def passed_before(key: str | None) -> bool:
    """Did this material pass before? Only a marker whose checksum holds and whose value is possible says so."""
    if key is None:
        return False
    try:
        raw = _marker(key).read_bytes()[:4096]
        doc = json.loads(raw.decode("utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return False
    return marker_values_possible(doc) and doc["key"] == key


def remember_pass(key: str | None, max_reflectance: float = 0.0) -> None:
    """Leave the marker (best effort: an unwritable cache only means checking again next time)."""
    if key is None or not (0.0 <= float(max_reflectance) < 1.0):
        return
    rho = float(max_reflectance)
    try:
        path = _marker(key)
        path.parent.mkdir(parents=True, exist_ok=True)
        atomicio.write_json(path, {"key": key, "max_reflectance": rho, "sha256": _marker_checksum(key, rho)},
                           fsync=False)
    except OSError:
        pass
