"""Materials already found energy-conserving, remembered on disk, so a repeat command skips the check.

:meth:`materials.material.Material.check_energy` integrates rho(theta_i) at 90 angles for both
polarizations (~1 s of every command's start-up for the glossy ``z302_sample_b``). A material that
passed leaves an empty marker file ``<cache>/energy_check/<key>``, key = SHA-256 of its material-file
dict (``Material.to_dict``, floats written exactly) and of the source of the ``materials`` package
(a changed model or quadrature checks again). Only passes are remembered: a material that fails is
checked, and refused, every time. ``STRAYLIGHT_CACHE=off`` turns the memo off (atomicio.cache_dirs).
"""
from __future__ import annotations

import hashlib
import json
from functools import lru_cache
from pathlib import Path

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


def passed_before(key: str | None) -> bool:
    return key is not None and _marker(key).is_file()


def remember_pass(key: str | None) -> None:
    """Leave the marker (best effort: an unwritable cache only means checking again next time)."""
    if key is None:
        return
    try:
        path = _marker(key)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.touch()
    except OSError:
        pass
