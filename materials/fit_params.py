"""What a component declares to be fitted: its free parameters, their bounds, scale and starts.

Each fittable model declares, in its own file, a class attribute ``fit_params``: a tuple of
:class:`FitParam`, one per parameter that :func:`materials.fit.fit` may vary (the rig diagnosis,
:mod:`rig.diagnose.params`, reads the same declarations). A component type without ``fit_params``
cannot be fitted. :func:`fit_params` is the one way to read them.

A parameter marked ``shared`` takes one value for every component of a model that declares it:
the refractive index :data:`REFRACTIVE_INDEX` (PHYSICS §1: one n explains s and p; a constant R
cannot), declared by every component with an index (k_correlation, microfacet).
"""
from __future__ import annotations

from dataclasses import dataclass

from materials.registry import component_types


@dataclass(frozen=True)
class FitParam:
    """One fittable parameter of a component.

    key : the component's key (CONTRACTS §5 spelling, unit-suffixed: ``sigma_nm``).
    lower, upper : bounds, in the key's unit.
    log : fitted in log space (a positive quantity spanning decades).
    start : the first start's value; None: the fit's data heuristic for the key, else the middle
        of the bounds (geometric for ``log``).
    plausible : (low, high) range of the random starts; None: start / 2 .. start x 2.
    shared : one value for every component of the model that declares it.
    """

    key: str
    lower: float
    upper: float
    log: bool
    start: float | None = None
    plausible: tuple[float, float] | None = None
    shared: bool = False

    @property
    def bounds(self) -> tuple[float, float, bool]:
        """``(lower, upper, log)``."""
        return (self.lower, self.upper, self.log)


#: The refractive index shared by every component that has one: n of paints, glasses and oxides.
REFRACTIVE_INDEX = FitParam("n", 1.05, 3.0, False, 1.5, (1.3, 1.9), shared=True)


def fittable_types() -> tuple[str, ...]:
    """Registered component types that declare ``fit_params``, sorted by name."""
    return tuple(sorted(t for t, cls in component_types().items() if getattr(cls, "fit_params", None)))


def fit_params(type_name: str) -> tuple[FitParam, ...]:
    """The :class:`FitParam` declarations of component type ``type_name``, in its declared order.

    KeyError (naming the fittable types) for a type that is not registered or declares none."""
    cls = component_types().get(type_name)
    params = getattr(cls, "fit_params", None) if cls is not None else None
    if not params:
        raise KeyError(f"component type {type_name!r} declares no fit_params; fittable: {', '.join(fittable_types())}")
    return tuple(params)


def fit_param(type_name: str, key: str) -> FitParam:
    """The declaration of parameter ``key`` of component type ``type_name``."""
    for p in fit_params(type_name):
        if p.key == key:
            return p
    raise KeyError(f"component type {type_name!r} has no fit parameter {key!r}")
