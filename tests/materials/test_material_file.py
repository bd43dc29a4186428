"""Material files (CONTRACTS §5): load / save / validation with one-line errors naming where."""
import json

import numpy as np
import pytest

import materials
from materials import Material, MaterialError, load_material, save_material
from materials.base import directions_from_angles

GOOD = {
    "name": "test_black",
    "wavelength_nm": 532.0,
    "description": "a test",
    "components": [
        {"type": "lambertian", "rd": 0.03},
        {"type": "k_correlation", "sigma_nm": 3.0, "lc_um": 40.0, "s": 2.4, "n": 1.52},
        {"type": "k_correlation", "sigma_nm": 25.0, "lc_um": 3.0, "s": 3.0, "n": [1.52, 0.01], "weight": 0.5},
        {"type": "abg", "a": 0.001, "b": 0.0001, "g": 2.0},
        {"type": "harvey_shack", "b0": 10.0, "l": 0.01, "s": -2.0},
    ],
}


def _write(tmp_path, text, name="m.json"):
    p = tmp_path / name
    p.write_text(text if isinstance(text, str) else json.dumps(text, indent=2))
    return p


def test_contracts_example_loads_and_round_trips(tmp_path):
    m = load_material(_write(tmp_path, GOOD))
    assert isinstance(m, Material) and m.name == "test_black" and len(m.components) == 5
    assert all(c.wavelength_nm == 532.0 for c in m.components if hasattr(c, "wavelength_nm"))
    out = save_material(tmp_path / "out" / "copy.json", m)
    assert json.loads(out.read_text()) == m.to_dict()
    assert [p.name for p in out.parent.iterdir()] == ["copy.json"]  # no temp file left
    again = load_material(out)
    wi, wo = directions_from_angles(np.deg2rad([10.0, 45, 80]), np.deg2rad([12.0, 44, 81]), 0.0)
    np.testing.assert_array_equal(again.brdf(wi, wo, "p"), m.brdf(wi, wo, "p"))
    assert again.to_dict() == m.to_dict()


def test_contracts_section5_example_verbatim_loads():
    text = """{
  "name": "z302_sample_b",
  "wavelength_nm": 532.0,
  "components": [
    {"type": "lambertian", "rd": 0.03},
    {"type": "k_correlation", "sigma_nm": 3.0, "lc_um": 40.0, "s": 2.4, "n": 1.52},
    {"type": "k_correlation", "sigma_nm": 25.0, "lc_um": 3.0, "s": 3.0, "n": 1.52, "weight": 0.5},
    {"type": "abg", "a": 0.001, "b": 0.0001, "g": 2.0},
    {"type": "harvey_shack", "b0": 10.0, "l": 0.01, "s": -2.0}
  ]
}"""
    m = load_material(json.loads(text))
    assert [type(c).__name__ for c in m.components] == ["Lambertian", "KCorrelation", "KCorrelation", "Abg", "HarveyShack"]
    assert m.components[2].weight == 0.5


def test_inline_dict_without_wavelength_and_name():
    m = load_material({"components": [{"type": "lambertian", "rd": 0.05}]}, name="black")
    assert m.name == "black" and m.wavelength_nm is None
    np.testing.assert_allclose(m.albedo(np.deg2rad([0.0, 60.0])), 0.05, rtol=1e-8)


def test_component_wavelength_overrides_and_is_kept(tmp_path):
    d = {"name": "x", "wavelength_nm": 532.0, "components": [{"type": "k_correlation", "sigma_nm": 1.0, "lc_um": 1.0, "s": 2.5, "r": 0.04, "wavelength_nm": 633.0}]}
    m = load_material(d)
    assert m.components[0].wavelength_nm == 633.0
    assert m.to_dict()["components"][0]["wavelength_nm"] == 633.0


def _error(source, **kw):
    with pytest.raises(MaterialError) as info:
        load_material(source, **kw)
    msg = str(info.value)
    assert "\n" not in msg and isinstance(info.value, ValueError)
    return msg


@pytest.mark.parametrize(
    "mutate,words",
    [
        (lambda d: d.update(colour="black"), ["unknown key", "colour"]),
        (lambda d: d["components"][1].update(sigma=3.0), ["components[1]", "unknown key", "sigma"]),
        (lambda d: d["components"][1].update(sigma_nm=-3.0), ["components[1]", "sigma_nm"]),
        (lambda d: d["components"][0].update(rd=1.0), ["components[0]", "rd"]),
        (lambda d: d["components"][2].update(type="phong"), ["components[2]", "unknown component type", "phong"]),
        (lambda d: d["components"][3].pop("g"), ["components[3]", "g"]),
        (lambda d: d["components"][1].pop("lc_um"), ["components[1]", "missing key(s) lc_um", "k_correlation"]),
        (lambda d: d["components"][4].update(l="wide"), ["components[4]", "'l'"]),
        (lambda d: d.update(components=[]), ["components", "non-empty"]),
        (lambda d: d.update(wavelength_nm=-1), ["wavelength_nm"]),
    ],
)
def test_bad_file_gives_one_line_error_naming_file_and_place(tmp_path, mutate, words):
    d = json.loads(json.dumps(GOOD))
    mutate(d)
    path = _write(tmp_path, d)
    msg = _error(path)
    assert str(path) in msg
    for w in words:
        assert w in msg, (w, msg)


def test_missing_wavelength_is_named(tmp_path):
    d = {"name": "x", "components": [{"type": "k_correlation", "sigma_nm": 1.0, "lc_um": 1.0, "s": 2.5, "n": 1.5}]}
    msg = _error(_write(tmp_path, d))
    assert "components[0]" in msg and "wavelength_nm" in msg


def test_invalid_json_names_line_and_column(tmp_path):
    path = _write(tmp_path, '{\n  "name": "x",\n  "components": [,]\n}\n')
    msg = _error(path)
    assert f"{path}:3:" in msg


def test_unknown_preset_and_missing_file():
    assert "z302_sample_a" in _error("no_such_material")
    assert "cannot read" in _error("/nonexistent/dir/m.json")


def test_energy_non_conserving_material_is_refused(tmp_path):
    """rho(theta_i) >= 1 at some theta_i in 0..89 deg (seed paper Eq. 3): a Lambertian 0.9 plus an
    ABg lobe with pi A / (B + 1) = 0.3 has rho = 1.2 everywhere."""
    a = 0.3 * 1.0001 / np.pi
    d = {"name": "hot", "components": [{"type": "lambertian", "rd": 0.9}, {"type": "abg", "a": a, "b": 0.0001, "g": 0.0}]}
    msg = _error(_write(tmp_path, d))
    assert "energy" in msg and "theta_i" in msg and "1.2" in msg
    m = load_material(d, check_energy=False)
    with pytest.raises(MaterialError, match="energy"):
        save_material(tmp_path / "hot.json", m)
    assert not (tmp_path / "hot.json").exists()


def test_presets_are_listed_and_load():
    presets = materials.list_presets()
    assert {"z302_sample_a", "z302_sample_b"} <= set(presets)
    for name in ("z302_sample_a", "z302_sample_b"):
        m = load_material(name)
        assert m.name == name and m.wavelength_nm == 532.0
        assert "not measured" in m.provenance.lower()


def test_material_pickles_for_distributed_workers():
    """Dask ships materials to workers by pickle; a round trip must sample identically."""
    import pickle

    m = load_material("z302_sample_b")
    wi, _ = directions_from_angles(np.full(50, 0.5), 0.0, 0.0)
    u = np.random.default_rng(0).random((50, 3))
    a = m.sample(wi, u, "s")
    b = pickle.loads(pickle.dumps(m)).sample(wi, u, "s")
    assert np.any(a.weight > 0)
    np.testing.assert_array_equal(a.weight, b.weight)
    np.testing.assert_array_equal(a.wo, b.wo)
