"""Capability declarations: components declare their physics (materials.flags), the
engine chooses each part's interaction kind, and what the estimators may do there, from those flags
in one registry (straylight.engine.interactions.registry; surface parts: one kind, surface_response,
whose capabilities are computed per material), and no code outside the registry recognises a kind by
its name. The estimator side (every kind and material class under every estimator) is
test_engine_contract.py."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

import materials
from materials.flags import ComponentFlags, flags_of
from materials.registry import component_types, register
from geometry.mesh import Part, Scene
from straylight.engine import second_vertex
from straylight.engine.interactions import (INTERACTIONS, Capability, Interaction, kind_for, kinds_with, parts_with,
                                            register_interaction)
from straylight.engine.interactions import registry
from straylight.trace import make_spec

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("name", sorted(component_types()))
def test_every_component_declares_flags(name):
    cls = component_types()[name]
    flags = flags_of(cls.example()) if hasattr(cls, "example") else cls.flags
    assert isinstance(flags, ComponentFlags) and flags != ComponentFlags.NONE
    # exactly one of: a scatter lobe, a delta interface
    assert bool(flags & ComponentFlags.SCATTER) != bool(flags & ComponentFlags.DELTA)


def test_register_refuses_a_component_without_flags():
    with pytest.raises(RuntimeError, match="must declare 'flags"):
        @register("no_flags_here")
        class NoFlags:  # noqa: F841
            pass
    assert "no_flags_here" not in component_types()


def test_material_flags_are_the_union_of_its_components():
    m = materials.load_material({"components": [{"type": "lambertian", "rd": 0.1}, {"type": "specular", "r": 0.5}]})
    assert m.flags == ComponentFlags.DIFFUSE | ComponentFlags.DELTA_REFLECTION | ComponentFlags.POLARIZING


LAMB = {"components": [{"type": "lambertian", "rd": 0.1}]}
MIRROR_COAT = {"components": [{"type": "specular", "n": [0.96, 6.69]}, {"type": "lambertian", "rd": 0.01}]}
WINDOW = {"components": [{"type": "dielectric", "n": 1.5}]}
SCATTER_CAPS = Capability.NEE | Capability.FIRST_VERTEX | Capability.SECOND_VERTEX | Capability.TARGET_MIS
FRESNEL_CAPS = Capability.NEE | Capability.REFLECTION_SPLIT | Capability.DELTA_CHAIN


def test_kind_and_capabilities_are_chosen_from_flags_not_names():
    lamb, mirror_coat, window = (materials.load_material(m) for m in (LAMB, MIRROR_COAT, WINDOW))
    surface = kind_for("surface", lamb)
    assert kind_for("surface", mirror_coat) is surface and kind_for("surface", window) is surface  # one kind
    assert surface.capabilities_for(lamb) == SCATTER_CAPS
    assert surface.capabilities_for(mirror_coat) == surface.capabilities_for(window) == FRESNEL_CAPS | Capability.POLARIZES
    assert not surface.allows(Capability.FIRST_VERTEX, mirror_coat) and not surface.allows(Capability.SECOND_VERTEX, window)
    # two algorithms, one per material class, each carrying its materials' capabilities
    assert surface.handler_for(lamb) is not surface.handler_for(mirror_coat)
    assert surface.handler_for(mirror_coat) is surface.handler_for(window)
    assert surface.handler_for(lamb).allows(Capability.TARGET_MIS)
    assert surface.label(lamb) == "surface_response (scatter)" and surface.label(window) == "surface_response (Fresnel)"
    assert kind_for("detector").terminal and kind_for("absorber").terminal
    assert not kind_for("mirror").terminal and kind_for("mirror").capabilities_for() == Capability.NONE

    class StandIn:  # a material object that declares nothing is a plain scatterer
        pass

    assert kind_for("surface", StandIn()) is surface and surface.capabilities_for(StandIn()) == SCATTER_CAPS


class _Declares:
    """A stand-in material that declares ``flags`` (what the rule reads, nothing else)."""

    def __init__(self, flags):
        self.flags = flags


@pytest.mark.parametrize("flags,expected", [
    (ComponentFlags.GLOSSY, SCATTER_CAPS),
    (ComponentFlags.DIFFUSE | ComponentFlags.POLARIZING, SCATTER_CAPS | Capability.POLARIZES),
    (ComponentFlags.DELTA_REFLECTION, FRESNEL_CAPS),
    (ComponentFlags.DELTA_TRANSMISSION | ComponentFlags.GLOSSY, FRESNEL_CAPS),
    (ComponentFlags.DELTA_TRANSMISSION | ComponentFlags.POLARIZING, FRESNEL_CAPS | Capability.POLARIZES),
])
def test_surface_capabilities_are_computed_from_every_flag(flags, expected):
    """DELTA_* choose the Fresnel algorithm and its capabilities, POLARIZING adds POLARIZES (the flag is
    read), DIFFUSE / GLOSSY alone make a pure scatterer."""
    assert kind_for("surface", _Declares(flags)).capabilities_for(_Declares(flags)) == expected


def _two_surface_spec(subject, wall):
    from tests.straylight.test_engine_contract import DETECTOR, FLOOR, WALL, _quad, _source

    scene = Scene((Part("subject", *_quad(*FLOOR), material="subject", role="surface"),
                   Part("wall", *_quad(*WALL), material="wall", role="surface"),
                   Part("detector", *_quad(*DETECTOR, n=2), role="detector")))
    mats = {"subject": materials.load_material(subject), "wall": materials.load_material(wall)}
    return make_spec(scene, _source(), 1000, 0, mats)


def test_capabilities_are_per_part_within_one_kind():
    """Two surface parts of the one kind: what the estimators may do follows each part's material, and
    second-vertex sampling stays out of a scene with a polarizing (Fresnel) part, naming it."""
    spec = _two_surface_spec(MIRROR_COAT, LAMB)
    assert list(parts_with(spec, Capability.FIRST_VERTEX)) == [False, True, False]
    assert list(parts_with(spec, Capability.DELTA_CHAIN)) == [True, False, False]
    assert [h.name for h in kinds_with(spec, Capability.POLARIZES)] == ["surface_response (Fresnel)"]
    assert "surface_response (Fresnel)" in second_vertex.unsupported(spec)
    assert second_vertex.unsupported(_two_surface_spec(LAMB, LAMB)) is None


def test_two_kinds_selected_by_the_same_flags_are_refused(monkeypatch):
    monkeypatch.setattr(registry, "INTERACTIONS", dict(INTERACTIONS))  # a kind of its own, for this test only

    @register_interaction
    class Lens(Interaction):
        name = "lens_kind"
        roles = ("surface",)
        selected_by = ComponentFlags.DELTA_TRANSMISSION

    assert kind_for("surface", materials.load_material(WINDOW)).name == "lens_kind"
    with pytest.raises(ValueError, match="both selected by"):
        @register_interaction
        class Rival(Interaction):
            name = "rival_delta"
            roles = ("surface",)
            selected_by = ComponentFlags.DELTA_TRANSMISSION
    with pytest.raises(ValueError, match="both selected by"):
        @register_interaction
        class SecondDefault(Interaction):
            name = "second_default"
            roles = ("surface",)
    assert "rival_delta" not in registry.INTERACTIONS and "second_default" not in registry.INTERACTIONS
    assert "lens_kind" not in INTERACTIONS


def _kind_name_comparisons(path: Path, names: set, base: Path = ROOT) -> list:
    """``x == "kind"`` / ``"kind" != x`` / ``x in ("kind", ...)`` with a registered kind's name."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    out = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Compare):
            continue
        consts = []
        for side in [node.left, *node.comparators]:
            if isinstance(side, ast.Constant):
                consts.append(side.value)
            elif isinstance(side, (ast.Tuple, ast.List, ast.Set)):
                consts += [e.value for e in side.elts if isinstance(e, ast.Constant)]
        if names & {c for c in consts if isinstance(c, str)}:
            out.append(f"{path.relative_to(base)}:{node.lineno}")
    return out


def _kind_labels() -> set:
    """Every registered kind's name and its labels per material class (``surface_response (Fresnel)``):
    none of them is compared outside the registry (a part's capabilities come from its material's flags)."""
    out = set(INTERACTIONS)
    for kind in INTERACTIONS.values():
        out |= {f"{kind.name} ({c})" for c in kind.material_classes if c}
    return out


def test_no_interaction_name_comparisons_outside_the_registry():
    names = _kind_labels()
    assert {"surface_response", "surface_response (Fresnel)", "surface_response (scatter)"} <= names
    registry_py = ROOT / "straylight" / "engine" / "interactions" / "registry.py"
    found = []
    for pkg in ("materials", "geometry", "straylight", "rig"):
        for path in sorted((ROOT / pkg).rglob("*.py")):
            if path != registry_py:
                found += _kind_name_comparisons(path, names)
    assert not found, f"interaction kinds recognised by name (use Capability / kind_for): {found}"


def test_the_scan_sees_a_name_comparison(tmp_path):
    """The scan above can fail: it finds the pattern the engine used before capability flags."""
    bad = tmp_path / "probe.py"
    bad.write_text('def f(m, kind):\n    return getattr(m, "interaction", "") == "surface_response" or kind in ("detection",)\n'
                   'def g(kind, m):\n    return kind.label(m) != "surface_response (Fresnel)"\n')
    assert sorted(_kind_name_comparisons(bad, _kind_labels(), tmp_path)) == ["probe.py:2", "probe.py:2", "probe.py:4"]


def test_register_refuses_a_component_that_is_neither_scatter_nor_delta():
    with pytest.raises(RuntimeError, match="exactly one of a scatter lobe"):
        @register("polarizing_only_here")
        class PolarizingOnly:  # noqa: F841
            flags = ComponentFlags.POLARIZING
    with pytest.raises(RuntimeError, match="exactly one of a scatter lobe"):
        @register("both_here")
        class Both:  # noqa: F841
            flags = ComponentFlags.DIFFUSE | ComponentFlags.DELTA_REFLECTION
    assert "polarizing_only_here" not in component_types() and "both_here" not in component_types()
