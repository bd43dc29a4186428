"""An energy-check marker (materials.energy_checked) is believed only when its checksum holds
AND its value is possible. On main 13a6b5b an empty file named by the material's key made a material
with a directional-hemispherical reflectance of 1.3 load without the check."""
from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest

from materials import MaterialError, load_material
from materials.energy_checked import _marker, check_key, passed_before
from materials.material import material_from_dict

HOT = {"name": "hot", "components": [{"type": "lambertian", "rd": 0.9},
                                     {"type": "abg", "a": 0.4 / np.pi, "b": 0.0001, "g": 0.0}]}


@pytest.fixture
def cache(monkeypatch, tmp_path):
    monkeypatch.setenv("STRAYLIGHT_CACHE", "on")
    monkeypatch.setenv("STRAYLIGHT_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path / "cache"


def _hot_key():
    return check_key(material_from_dict(HOT, check_energy=False))


def _forge(key: str, content: str) -> None:
    path = _marker(key)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(content)


@pytest.mark.parametrize("rho", [3.14, -0.5, 1.0])
def test_marker_with_recomputed_checksum_but_impossible_value_ignored(cache, rho):
    key = _hot_key()
    checksum = hashlib.sha256(f"{key}\n{rho!r}".encode()).hexdigest()  # a forger recomputes it
    _forge(key, json.dumps({"key": key, "max_reflectance": rho, "sha256": checksum}))
    assert not passed_before(key)
    with pytest.raises(MaterialError, match="energy"):
        load_material(HOT)


@pytest.mark.parametrize("content", ["", "{}", "not json", '{"key": "other", "max_reflectance": 0.5, "sha256": "x"}'])
def test_empty_or_foreign_marker_ignored(cache, content):
    key = _hot_key()
    _forge(key, content)
    with pytest.raises(MaterialError, match="energy"):
        load_material(HOT)


def test_a_real_pass_is_remembered_with_its_value(cache):
    good = {"name": "g", "components": [{"type": "lambertian", "rd": 0.05}]}
    load_material(good)
    key = check_key(material_from_dict(good, check_energy=False))
    doc = json.loads(_marker(key).read_text())
    assert doc["max_reflectance"] == pytest.approx(0.05, rel=0.02)  # a Lambertian's DHR is rd
    assert passed_before(key)
