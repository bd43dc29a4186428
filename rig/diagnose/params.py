"""Model space of the diagnosis: optimiser variables with their bounds, a model (material values
+ effect parameters) and a fit. Bounds come from one place per model: the material components'
``fit_params`` (declared in materials/lambertian.py and materials/kcorrelation.py, read through
:func:`materials.fit_params.fit_param`, as materials.fit does) and each effect's ``fit_space`` (its
own file in rig/effects/)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import materials.kcorrelation  # noqa: F401  (registers "k_correlation" and its fit_params)
import materials.lambertian  # noqa: F401  (registers "lambertian" and its fit_params)
from materials.fit_params import fit_param
from rig.diagnose.fast_material import FitMaterial
from rig.effects import build_effect, effect_types


@dataclass(frozen=True)
class ParamSpec:
    """One optimiser variable: which object it belongs to, its name, bounds and scale."""

    owner: str  # "material" or an effect name
    name: str
    lo: float
    hi: float
    scale: str  # "lin" | "log"

    def to_x(self, value):
        return math.log10(value) if self.scale == "log" else float(value)

    def from_x(self, x):
        return 10.0**x if self.scale == "log" else float(x)

    @property
    def bounds_x(self):
        return (self.to_x(self.lo), self.to_x(self.hi))


def _spec(owner, name, bounds):
    lo, hi, log = bounds
    return ParamSpec(owner, name, lo, hi, "log" if log else "lin")


def material_specs(n_lobes: int):
    """rd, then (sigma, lc, s) per lobe, then the shared n: bounds from the components' fit_params."""
    specs = [_spec("material", "rd", fit_param("lambertian", "rd").bounds)]

    def kc(key):
        return fit_param("k_correlation", key).bounds

    for k in range(n_lobes):
        specs += [_spec("material", f"sigma{k}_nm", kc("sigma_nm")), _spec("material", f"lc{k}_um", kc("lc_um")),
                  _spec("material", f"s{k}", kc("s"))]
    specs.append(_spec("material", "n", kc("n")))
    return specs


def effect_specs(name: str):
    cls = effect_types()[name]
    return [ParamSpec(name, p, lo, hi, scale) for p, (lo, hi, scale, _) in cls.fit_space.items()]


@dataclass
class Model:
    """A point in model space: material values and effect parameter values."""

    n_lobes: int
    values: dict  # (owner, name) -> value
    effects: tuple = ()  # effect names, in the order added

    def material(self, wavelength_nm) -> FitMaterial:
        v = self.values
        lobes = tuple((v[("material", f"sigma{k}_nm")], v[("material", f"lc{k}_um")], v[("material", f"s{k}")])
                      for k in range(self.n_lobes))
        return FitMaterial(v[("material", "rd")], lobes, v[("material", "n")], wavelength_nm)

    def effect_objects(self):
        out = []
        for name in self.effects:
            params = {p: self.values[(name, p)] for p in effect_types()[name].fit_space}
            out.append(build_effect(name, **params))
        return out

    def effect_params(self, name):
        return {p: self.values[(name, p)] for p in effect_types()[name].fit_space}

    def specs(self):
        s = material_specs(self.n_lobes)
        for name in self.effects:
            s += effect_specs(name)
        return s


@dataclass
class Fit:
    model: Model
    chi2: float
    k: int
    n_points: int
    success: bool
    nfev: int

    @property
    def bic(self) -> float:
        return self.chi2 + self.k * math.log(max(self.n_points, 1))
