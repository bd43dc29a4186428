"""Capability declarations: components declare their physics (materials.flags), the
engine chooses each part's interaction kind from those flags in one registry
(straylight.engine.interactions.registry), and no code outside the registry recognises a kind by
its name. The estimator side (every kind under every estimator) is test_engine_contract.py."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

import materials
from materials.flags import ComponentFlags, flags_of
from materials.registry import component_types, register
from straylight.engine.interactions import INTERACTIONS, Capability, Interaction, kind_for, register_interaction

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


def test_kind_is_chosen_from_flags_not_names():
    lamb = materials.load_material({"components": [{"type": "lambertian", "rd": 0.1}]})
    mirror_coat = materials.load_material({"components": [{"type": "specular", "n": [0.96, 6.69]},
                                                           {"type": "lambertian", "rd": 0.01}]})
    window = materials.load_material({"components": [{"type": "dielectric", "n": 1.5}]})
    scatter, optical = kind_for("surface", lamb), kind_for("surface", mirror_coat)
    assert kind_for("surface", window) is optical and scatter is not optical
    assert scatter.allows(Capability.FIRST_VERTEX | Capability.SECOND_VERTEX | Capability.NEE)
    assert optical.allows(Capability.NEE) and optical.allows(Capability.POLARIZES)
    assert not optical.allows(Capability.FIRST_VERTEX) and not optical.allows(Capability.SECOND_VERTEX)
    assert kind_for("detector").terminal and kind_for("absorber").terminal
    assert not kind_for("mirror").terminal and kind_for("mirror").capabilities == Capability.NONE

    class StandIn:  # a material object that declares nothing is a plain scatterer
        pass

    assert kind_for("surface", StandIn()) is scatter


def test_two_kinds_selected_by_the_same_flags_are_refused():
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
    assert "rival_delta" not in INTERACTIONS and "second_default" not in INTERACTIONS


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


def test_no_interaction_name_comparisons_outside_the_registry():
    names = set(INTERACTIONS)
    registry = ROOT / "straylight" / "engine" / "interactions" / "registry.py"
    found = []
    for pkg in ("materials", "geometry", "straylight", "rig"):
        for path in sorted((ROOT / pkg).rglob("*.py")):
            if path != registry:
                found += _kind_name_comparisons(path, names)
    assert not found, f"interaction kinds recognised by name (use Capability / kind_for): {found}"


def test_the_scan_sees_a_name_comparison(tmp_path):
    """The scan above can fail: it finds the pattern the engine used before capability flags."""
    bad = tmp_path / "probe.py"
    bad.write_text('def f(m, kind):\n    return getattr(m, "interaction", "") == "optical_surface" or kind in ("detection",)\n')
    assert _kind_name_comparisons(bad, set(INTERACTIONS), tmp_path) == ["probe.py:2", "probe.py:2"]
