"""The energy check is remembered per material (materials.energy_checked): a repeat load skips the
integrals, a changed material or a failing one is checked every time, STRAYLIGHT_CACHE=off checks always."""
import numpy as np
import pytest

import materials.material as material_mod
from materials import MaterialError, load_material

GLOSSY = {"name": "g", "components": [{"type": "lambertian", "rd": 0.05}, {"type": "abg", "a": 0.01, "b": 0.001, "g": 2.0}]}
HOT = {"name": "hot", "components": [{"type": "lambertian", "rd": 0.9},
                                     {"type": "abg", "a": 0.3 * 1.0001 / np.pi, "b": 0.0001, "g": 0.0}]}


@pytest.fixture
def counted(monkeypatch, tmp_path):
    monkeypatch.setenv("STRAYLIGHT_CACHE", "on")
    monkeypatch.setenv("STRAYLIGHT_CACHE_DIR", str(tmp_path))
    calls = []
    real = material_mod.directional_hemispherical_reflectance

    def counting(*args, **kwargs):
        calls.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(material_mod, "directional_hemispherical_reflectance", counting)
    return calls


def test_a_passed_material_is_not_integrated_again(counted):
    load_material(GLOSSY)
    first = len(counted)
    assert first >= 2  # s and p
    load_material(GLOSSY)
    assert len(counted) == first
    changed = dict(GLOSSY, components=[GLOSSY["components"][0], dict(GLOSSY["components"][1], g=2.5)])
    load_material(changed)
    assert len(counted) > first  # another material: checked


def test_a_failing_material_is_refused_every_time(counted):
    for _ in range(2):
        with pytest.raises(MaterialError, match="energy"):
            load_material(HOT)
    assert len(counted) >= 4


def test_cache_off_checks_every_time(counted, monkeypatch):
    monkeypatch.setenv("STRAYLIGHT_CACHE", "off")
    load_material(GLOSSY)
    first = len(counted)
    load_material(GLOSSY)
    assert len(counted) == 2 * first
