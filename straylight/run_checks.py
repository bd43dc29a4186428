"""Warnings for numbers that would otherwise be silently wrong.

- :func:`check_truncation`: a ray still carrying power after ``max_events`` surface events is
  stopped and its power counted as absorbed (the ledger's ``truncated_w``). Above
  :data:`TRUNCATION_WARN_FRACTION` of the emitted power that is no longer round-off: a
  :class:`TruncationWarning` says how much was cut and what to raise.
- :func:`check_origin_precision`: Embree intersects in float32, so a ray origin at a distance D
  from the world origin is rounded by up to D 2^-24 before any hit is found. A source 1e17 mm away
  (origins rounded by ~6e9 mm) lost every ray without a word. Rounding above
  :data:`PRECISION_WARN_FRACTION` of the scene's size is a :class:`PrecisionWarning`; above
  :data:`PRECISION_REFUSE_FRACTION` the trace is refused (the rays would miss or hit the wrong
  parts). Sources are virtual: moving one closer along its beam changes nothing else.
"""
from __future__ import annotations

import math
import warnings

import numpy as np

TRUNCATION_WARN_FRACTION = 0.01
PRECISION_WARN_FRACTION = 1e-4
PRECISION_REFUSE_FRACTION = 1e-2
PART_EPS_WARN_FRACTION = 1e-2
PART_EPS_REFUSE_FRACTION = 1e-1
FLOAT32_HALF_ULP = 2.0 ** -24  # relative rounding of a float64 -> float32 cast (round to nearest)


class TruncationWarning(UserWarning):
    """More than a threshold of the emitted power was stopped by ``max_events``."""


class PrecisionWarning(UserWarning):
    """Ray origins far from the world origin lose precision in Embree's float32."""


def truncation_message(truncated_w: float, emitted_w: float, max_events: int) -> str | None:
    """The warning text when ``truncated_w`` is above the threshold fraction of ``emitted_w``, else None."""
    if not emitted_w > 0 or not truncated_w > TRUNCATION_WARN_FRACTION * emitted_w:
        return None
    return (f"max_events = {max_events} stopped {truncated_w / emitted_w:.1%} of the emitted power "
            f"({truncated_w:.3g} W, counted as absorbed): raise --max-events (PhysicsOptions.max_events)")


def check_truncation(result, max_events: int) -> None:
    """Warn (:class:`TruncationWarning`) if ``result``'s ledger shows truncation above the threshold."""
    message = truncation_message(float(result.ledger["truncated_w"].power_w), float(result.emitted_w), int(max_events))
    if message:
        warnings.warn(message, TruncationWarning, stacklevel=3)


def origin_rounding_mm(source, n: int = 64) -> float:
    """The largest float32 rounding of ``source``'s ray origins (mm), from ``n`` deterministic probe rays."""
    u = np.random.default_rng(0).random((n, 4))
    origins, _ = source.emit(u)
    return float(np.max(np.abs(origins))) * FLOAT32_HALF_ULP


def check_origin_precision(sources, bounds_mm) -> None:
    """Refuse (ValueError) or warn (:class:`PrecisionWarning`) for sources whose ray origins float32
    rounds by more than the fractions of the scene's size in the module doc."""
    lo, hi = (np.asarray(b, dtype=np.float64) for b in bounds_mm)
    size_mm = float(np.linalg.norm(hi - lo))
    if not size_mm > 0 or not math.isfinite(size_mm):
        return
    for i, src in enumerate(sources, start=1):
        try:
            rounding = origin_rounding_mm(src)
        except Exception:  # noqa: BLE001 - a source this probe cannot sample is checked where it is traced
            continue
        if not math.isfinite(rounding) or rounding <= PRECISION_WARN_FRACTION * size_mm:
            continue
        text = (f"source {i} emits up to {rounding / FLOAT32_HALF_ULP:.3g} mm from the origin, where the tracer's "
                f"float32 rounds ray origins by up to {rounding:.3g} mm ({rounding / size_mm:.2g} of the scene's "
                f"{size_mm:.3g} mm)")
        advice = "move it closer along its beam (sources are virtual: nothing else changes)"
        if rounding > PRECISION_REFUSE_FRACTION * size_mm:
            raise ValueError(f"{text}: rays would miss or hit the wrong parts; {advice}")
        warnings.warn(f"{text}; {advice}", PrecisionWarning, stacklevel=3)


def check_part_precision(parts, eps_mm: float) -> None:
    """Refuse (ValueError) or warn (:class:`PrecisionWarning`) when the self-intersection offset
    ``eps_mm`` is above the fractions of the smallest part's size (bounding-box diagonal) in the
    module doc; the message names that part and the farthest one."""
    if not parts or not eps_mm > 0:
        return
    sizes, reach = [], []
    for p in parts:
        v = np.asarray(p.vertices_mm, dtype=np.float64)
        lo, hi = v.min(axis=0), v.max(axis=0)
        sizes.append(float(np.linalg.norm(hi - lo)))
        reach.append(float(max(np.abs(lo).max(), np.abs(hi).max())))
    small = int(np.argmin(sizes))
    far = int(np.argmax(reach))
    fraction = eps_mm / sizes[small] if sizes[small] > 0 else math.inf
    if fraction <= PART_EPS_WARN_FRACTION:
        return
    text = (f"part {parts[far].name!r} reaches {reach[far]:.3g} mm from the origin, where the tracer's float32 "
            f"self-intersection offset is {eps_mm:.3g} mm, {fraction:.2g} of the smallest part "
            f"({parts[small].name!r}, {sizes[small]:.3g} mm)")
    advice = "place the parts near the origin (results would be biased)"
    if fraction > PART_EPS_REFUSE_FRACTION:
        raise ValueError(f"{text}; {advice}")
    warnings.warn(f"{text}; {advice}", PrecisionWarning, stacklevel=3)
