"""Component registry: ``@register("abg")`` on a model class; ``build(dict)`` makes one.

A registered class must be a dataclass whose fields are the component keys of
CONTRACTS §5, which provides the :class:`materials.base.Brdf` protocol (or, for a delta
component, ``coefficients``) and which declares what it is: ``flags``, a
:class:`materials.flags.ComponentFlags` (the tracer chooses the surface interaction from them).
"""
from __future__ import annotations

import dataclasses
import importlib

from materials.base import MaterialError
from materials.flags import ComponentFlags

_REGISTRY: dict[str, type] = {}
#: component types whose module is imported on first use (a measured BSDF table: only files that name it
#: pay for its module); importing ``materials`` registers the others
_ON_FIRST_USE = {"bsdf_table": "materials.bsdf_table"}


def register(type_name: str):
    def decorate(cls):
        if type_name in _REGISTRY and _REGISTRY[type_name] is not cls:
            raise RuntimeError(f"component type {type_name!r} registered twice")
        flags = getattr(cls, "flags", None)
        if not isinstance(flags, (ComponentFlags, property)):
            raise RuntimeError(f"component type {type_name!r} ({cls.__name__}) must declare "
                               "'flags = ComponentFlags...' (materials.flags)")
        if isinstance(flags, ComponentFlags) and bool(flags & ComponentFlags.SCATTER) == bool(flags & ComponentFlags.DELTA):
            raise RuntimeError(f"component type {type_name!r} ({cls.__name__}) must be exactly one of a scatter lobe "
                               "(DIFFUSE or GLOSSY) and a delta interface (DELTA_REFLECTION, DELTA_TRANSMISSION)")
        _REGISTRY[type_name] = cls
        cls.type_name = type_name
        return cls

    return decorate


def component_types() -> dict[str, type]:
    for type_name in _ON_FIRST_USE:
        _imported(type_name)
    return dict(_REGISTRY)


def _imported(type_name: str) -> type | None:
    """The registered class of ``type_name``, importing its module first when it is one of :data:`_ON_FIRST_USE`."""
    cls = _REGISTRY.get(type_name)
    if cls is None and type_name in _ON_FIRST_USE:
        importlib.import_module(_ON_FIRST_USE[type_name])
        cls = _REGISTRY.get(type_name)
    return cls


def build_component(entry: dict, where: str = "component"):
    """Build one component from its dict; unknown type or keys are a MaterialError naming ``where``."""
    if not isinstance(entry, dict) or "type" not in entry:
        raise MaterialError(f"{where}: a component needs a 'type' key")
    type_name = entry["type"]
    cls = _imported(type_name) if isinstance(type_name, str) else None
    if cls is None:
        raise MaterialError(
            f"{where}: unknown component type {type_name!r}; known: {', '.join(sorted({*_REGISTRY, *_ON_FIRST_USE}))}"
        )
    known = {f.name for f in dataclasses.fields(cls)}
    kwargs = {k: v for k, v in entry.items() if k != "type"}
    unknown = sorted(set(kwargs) - known)
    if unknown:
        raise MaterialError(
            f"{where}: unknown key(s) {', '.join(unknown)} for type {type_name!r}; allowed: {', '.join(sorted(known))}"
        )
    required = sorted(f.name for f in dataclasses.fields(cls) if f.init and f.default is dataclasses.MISSING
                      and f.default_factory is dataclasses.MISSING and f.name not in kwargs)
    if required:
        raise MaterialError(f"{where}: missing key(s) {', '.join(required)} for type {type_name!r}")
    try:
        return cls(**kwargs)
    except TypeError as exc:
        raise MaterialError(f"{where}: {exc}") from None
