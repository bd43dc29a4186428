"""Source polarization (CONTRACTS §6.3): ``polarization = "unpolarized"`` (default) or ``"linear"``
with ``e_field = [x, y, z]`` normal to the source's ``direction``.

The scene file's keys are read here, apart from the source's own keys (``straylight.sources``), and
the result is attached to the source object as ``source.polarization`` (a
:class:`SourcePolarization`), which the tracer reads with ``getattr(src, "polarization", UNPOLARIZED)``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

KINDS = ("unpolarized", "linear")
KEYS = ("polarization", "e_field")


class PolarizationError(ValueError):
    """Bad polarization keys of a source; the message names the entry."""


@dataclass(frozen=True)
class SourcePolarization:
    """``kind`` is ``"unpolarized"`` or ``"linear"``; ``e_field`` a unit (3,) vector for linear light."""

    kind: str = "unpolarized"
    e_field: Optional[tuple] = None

    @property
    def is_linear(self) -> bool:
        return self.kind == "linear"


UNPOLARIZED = SourcePolarization()


def split_polarization(entry: dict, where: str = "source"):
    """``(entry without polarization keys, SourcePolarization)``; one-line errors naming ``where``."""
    if not isinstance(entry, dict):
        return entry, UNPOLARIZED
    rest = {k: v for k, v in entry.items() if k not in KEYS}
    kind = entry.get("polarization", "unpolarized")
    if kind not in KINDS:
        raise PolarizationError(f"{where}: polarization must be one of {', '.join(KINDS)}, got {kind!r}")
    e = entry.get("e_field")
    if kind == "unpolarized":
        if e is not None:
            raise PolarizationError(f"{where}: 'e_field' is only for polarization = \"linear\"")
        return rest, UNPOLARIZED
    if e is None:
        raise PolarizationError(f"{where}: polarization = \"linear\" needs e_field = [x, y, z]")
    try:
        v = np.asarray(e, float)
    except (TypeError, ValueError):
        v = np.zeros(0)
    if v.shape != (3,) or not np.all(np.isfinite(v)) or np.linalg.norm(v) == 0:
        raise PolarizationError(f"{where}: e_field must be a non-zero [x, y, z], got {e!r}")
    v = v / np.linalg.norm(v)
    return rest, SourcePolarization("linear", tuple(float(x) for x in v))


def check_polarization_for_source(pol: SourcePolarization, source, where: str = "source") -> None:
    """Linear light needs a source with one propagation direction, and e_field normal to it
    (|e . direction| <= 1e-6)."""
    if not pol.is_linear:
        return
    direction = getattr(source, "direction", None)
    if direction is None:
        raise PolarizationError(f"{where}: polarization = \"linear\" needs a collimated source (one direction)")
    d = np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    if pol.e_field is None:
        raise PolarizationError(f"{where}: polarization = \"linear\" needs an e_field")
    dot = float(np.dot(d, pol.e_field))
    if abs(dot) > 1e-6:
        raise PolarizationError(f"{where}: e_field must be normal to the source direction (e . d = {dot:.3g})")


def attach(source, pol: SourcePolarization):
    """Set ``source.polarization`` (sources are frozen dataclasses; the attribute travels with them,
    pickled to dask workers too) and return the source."""
    object.__setattr__(source, "polarization", pol)
    return source
