"""Every fittable model declares its fit parameters in its own file; materials.fit reads them through
materials.fit_params only ("every model's fit bounds in its own file")."""
import ast
import dataclasses
from pathlib import Path

import numpy as np
import pytest

import materials
import materials.registry
from materials.fit import FitError, ModelSpec, fit
from materials.fit_params import REFRACTIVE_INDEX, FitParam, fit_param, fit_params, fittable_types
from materials.registry import component_types, register

ROOT = Path(__file__).resolve().parents[2]


def test_each_fittable_model_declares_its_parameters_in_its_own_module():
    assert fittable_types() == ("abg", "harvey_shack", "k_correlation", "lambertian", "microfacet")
    for type_name in fittable_types():
        cls = component_types()[type_name]
        assert "fit_params" in vars(cls), type_name  # the class's own declaration, not inherited
        fields = {f.name for f in dataclasses.fields(cls)}
        for p in fit_params(type_name):
            assert p.key in fields, (type_name, p.key)  # a key the component is built with
            assert p.lower < p.upper and (not p.log or p.lower > 0), (type_name, p)
            if p.start is not None:
                assert p.lower <= p.start <= p.upper, (type_name, p)
    # the one shared index: every component with an index declares the same object
    assert [t for t in fittable_types() if REFRACTIVE_INDEX in fit_params(t)] == ["k_correlation", "microfacet"]
    with pytest.raises(KeyError, match="declares no fit_params"):
        fit_params("dielectric")
    with pytest.raises(KeyError, match="no fit parameter 'x'"):
        fit_param("abg", "x")


def test_fit_module_holds_no_bounds_of_its_own():
    """materials/fit.py builds no FitParam and names no model type: it reads the declarations."""
    tree = ast.parse((ROOT / "materials" / "fit.py").read_text())
    names = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)}
    strings = {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)}
    assert "FitParam" not in {n.func.id for n in ast.walk(tree) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)}
    assert not names & {"FIT_BOUNDS", "_PARAMS"}
    assert not strings & set(fittable_types()), strings & set(fittable_types())


def test_spec_takes_bounds_order_and_shared_index_from_the_declarations():
    spec = ModelSpec("lambertian+k_correlation+microfacet", 532.0)
    assert [d.name for d in spec.all_params] == [
        "lambertian.rd", "k_correlation.sigma_nm", "k_correlation.lc_um", "k_correlation.s",
        "microfacet.alpha", "microfacet.weight", "n"]
    for d in spec.all_params:
        declared = fit_param(d.name.split(".")[0], d.key) if d.component is not None else REFRACTIVE_INDEX
        assert (d.lower, d.upper, d.log, d.start, d.plausible) == (
            declared.lower, declared.upper, declared.log, declared.start, declared.plausible)
    comps = spec.components(spec.to_x({d.name: d.start or 0.03 for d in spec.free}))
    assert comps[1].n == comps[2].n == 1.5 and comps[1].wavelength_nm == 532.0  # one n; lobe at the scan's wavelength


@dataclasses.dataclass(frozen=True)
class _Floor:
    """A constant BRDF, for the test below: f = level (1/sr)."""

    level: float
    flags = materials.lambertian.Lambertian.flags
    fit_params = (FitParam("level", 1e-6, 1.0, True, 0.01, (1e-3, 0.1)),)

    def brdf(self, wi, wo, pol="u"):
        return np.full(len(wi), self.level)


def test_a_new_model_is_fittable_by_its_declaration_alone(monkeypatch):
    """Registering a component with ``fit_params`` makes it fittable with no change to materials.fit;
    its constant level is recovered from constant data (the weighted mean in log space)."""
    monkeypatch.setattr(materials.registry, "_REGISTRY", dict(materials.registry._REGISTRY))
    with pytest.raises(FitError, match="unknown component type 'floor'"):
        ModelSpec("floor", 532.0)
    register("floor")(_Floor)
    from materials.scan import make_scan

    n = 12
    scan = make_scan(wavelength_nm=532.0, polarization=np.full(n, "s"), theta_i_deg=np.full(n, 30.0),
                     theta_r_deg=np.linspace(-60, 60, n), phi_r_deg=0.0, brdf_per_sr=np.full(n, 0.02),
                     brdf_std_per_sr=np.full(n, 0.001), n_repeats=3)
    res = fit(scan, "floor", n_starts=2, seed=0)
    assert res.params["floor.level"] == pytest.approx(0.02, rel=1e-6)
