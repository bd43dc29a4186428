"""docs/reference/ stays in step with the code: every command the parser has, every scene key, source
and surface type, every material component and its keys, every scan column and every instrument-effect name is
described there; help texts point there, never at the specification users do not have."""
import argparse
import dataclasses
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
REF = ROOT / "docs" / "reference"


def _page(name: str) -> str:
    return (REF / name).read_text(encoding="utf-8")


def _ticked(text: str) -> set:
    return set(re.findall(r"`([^`]+)`", text))


def _commands():
    from straylight.cli.main import build_parser

    def walk(parser, path=()):
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    subs = [a for a in sub._actions if isinstance(a, argparse._SubParsersAction)]
                    if subs:
                        yield from walk(sub, (*path, name))
                    else:
                        yield (*path, name), sub

    return list(walk(build_parser()))


def test_every_command_has_its_section():
    text = _page("commands.md")
    headings = "\n".join(line for line in text.splitlines() if line.startswith("### "))
    missing = [" ".join(path) for path, _ in _commands() if f"`straylight {' '.join(path)}`" not in headings]
    assert not missing, f"docs/reference/commands.md lacks: {missing}"


def test_every_scene_key_source_and_surface_is_described():
    from geometry.analytic import _KEYS as SURFACES
    from geometry.io import PART_KEYS, SOLID_KEYS
    from straylight.analyses.scene_setup import ANALYSIS_KEYS, ENTRANCE_KEYS
    from straylight.polarization import KEYS as POLARIZATION_KEYS
    from straylight.scene import TOP_KEYS
    from straylight.sources import _KEYS as SOURCES

    text = _page("scene.md")
    words = _ticked(text) | set(re.findall(r"[A-Za-z_0-9]+", text))
    keys = set(PART_KEYS) | set(SOLID_KEYS) | set(TOP_KEYS) | set(ANALYSIS_KEYS) | set(ENTRANCE_KEYS)
    keys |= set(POLARIZATION_KEYS) | set(SOURCES) | {k for req, opt in SOURCES.values() for k in req | opt}
    keys |= set(SURFACES) | {k for ks in SURFACES.values() for k in ks}
    assert not sorted(keys - words), f"docs/reference/scene.md lacks: {sorted(keys - words)}"


def test_every_material_component_and_key_is_described():
    import importlib
    import pkgutil

    import materials  # noqa: F401 - registers the components
    for module in pkgutil.iter_modules(materials.__path__):  # and those registered by their own module
        importlib.import_module(f"materials.{module.name}")
    from materials.material import TOP_LEVEL_KEYS
    from materials.registry import component_types

    text = _page("material.md")
    words = set(re.findall(r"[A-Za-z_0-9]+", text))
    missing = set(TOP_LEVEL_KEYS) - words
    for name, cls in component_types().items():
        missing |= ({name} | {f.name for f in dataclasses.fields(cls)}) - words
    assert not missing, f"docs/reference/material.md lacks: {sorted(missing)}"


def test_scan_columns_and_effect_names_are_described():
    from materials.scan import CSV_COLUMNS

    rig_effects = pytest.importorskip("rig.effects")
    assert set(CSV_COLUMNS) <= _ticked(_page("scan-csv.md"))
    assert set(rig_effects.CATALOGUE) <= _ticked(_page("effects.md"))


def test_help_points_at_the_reference_pages_and_they_exist():
    from straylight.cli.main import build_parser

    texts = []

    def walk(parser):
        texts.append(parser.format_help())
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for sub in action.choices.values():
                    walk(sub)

    walk(build_parser())
    help_text = "\n".join(texts)
    assert "CONTRACTS" not in help_text and "shared/" not in help_text
    for page in set(re.findall(r"docs/reference/([\w.-]+\.md)", help_text)) | {"README.md"}:
        assert (REF / page).is_file(), page
    index = _page("README.md")
    assert all(f"({p.name})" in index for p in REF.glob("*.md") if p.name != "README.md")
