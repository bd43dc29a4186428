"""Effect registry: ``@register_effect("angle_offset")`` on a frozen dataclass.

An instrument effect (CONTRACTS §3) is a frozen dataclass whose fields are its
parameters (unit-suffixed names) and which provides ``wrap(forward) -> forward``
with the forward-model signature of :data:`rig.forward.Forward`. At zero strength
(the field defaults) ``wrap`` returns ``forward`` itself: exactly the identity.

Each class also declares ``fit_space``: for each parameter, ``(lower, upper, scale,
starts)``, with ``scale`` "lin" or "log" and ``starts`` a tuple of starting values
(``None`` entries are filled from the data: the class's optional
``starts_from_data(signal_per_sr) -> {param: [values]}``, given the training readings
BRDF x cos(theta_r); the middle of the range otherwise). ``region`` names the scan region where
the effect mostly acts (used to flag confounded effects). Everything effect-specific the
diagnosis needs lives in the effect's own file.
"""
from __future__ import annotations

import dataclasses
from typing import Any, Protocol, cast


class EffectError(ValueError):
    """Unknown effect name or bad effect parameter; the message names it."""


class EffectClass(Protocol):
    """What the diagnosis reads from a registered effect class (class attributes; calling it makes the effect)."""

    name: str
    fit_space: dict[str, tuple]  # parameter -> (lower, upper, "lin" | "log", starts)
    region: str

    def __call__(self, **params: Any) -> Any: ...


class TwinnedEffectClass(EffectClass, Protocol):
    """An effect with a twin: another effect the data can hardly tell from it, and the twin's
    parameters that imitate given ones."""

    twin: str

    def twin_params(self, **params: float) -> dict[str, float]: ...


_EFFECTS: dict[str, Any] = {}  # name -> the registered class (an EffectClass)


def register_effect(name: str):
    def decorate(cls):
        if name in _EFFECTS and _EFFECTS[name] is not cls:
            raise RuntimeError(f"effect {name!r} registered twice")
        _EFFECTS[name] = cls
        cls.name = name
        return cls

    return decorate


def effect_types() -> dict[str, EffectClass]:
    """name -> class, in registration order."""
    return dict(_EFFECTS)


def twin_of(name: str) -> TwinnedEffectClass | None:
    """The class of effect ``name`` if it declares a twin (``twin``, ``twin_params``), else None."""
    cls = _EFFECTS.get(name)
    return cast(TwinnedEffectClass, cls) if cls is not None and hasattr(cls, "twin") else None


def effect_names() -> list[str]:
    return list(_EFFECTS)


def build_effect(name: str, **params):
    """The effect ``name`` with ``params`` (unknown name or keys raise :class:`EffectError`)."""
    cls = _EFFECTS.get(name)
    if cls is None:
        raise EffectError(f"unknown effect {name!r}; known: {', '.join(_EFFECTS)}")
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(params) - known)
    if unknown:
        raise EffectError(f"effect {name!r}: unknown parameter(s) {', '.join(unknown)}; allowed: {', '.join(sorted(known))}")
    return cls(**params)


def check_param(effect: str, name: str, value, lo=None, hi=None, allow_none=False, allow_inf=False):
    """Validate one numeric parameter; returns it as float (or None)."""
    import math

    if value is None and allow_none:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise EffectError(f"effect {effect!r}: parameter {name} must be a number, got {value!r}")
    value = float(value)
    if math.isnan(value) or (math.isinf(value) and not allow_inf):
        raise EffectError(f"effect {effect!r}: parameter {name} must be finite, got {value!r}")
    if lo is not None and value < lo:
        raise EffectError(f"effect {effect!r}: parameter {name} must be >= {lo}, got {value!r}")
    if hi is not None and value > hi:
        raise EffectError(f"effect {effect!r}: parameter {name} must be <= {hi}, got {value!r}")
    return value
