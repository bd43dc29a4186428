"""End-to-end diagnosis on synthetic scans (rig.synth: a QMC ray-geometry path, not the fit's
quadrature) of a Z302-sample-B-like material, with effects injected at the SCORE_CASES
("visible") strengths: alignment and detector errors a hand-aligned reflectometer can have,
leaving a baseline held-out gap of 1.9-7.5x the noise level.

Pass criteria: the injected effect ranks first and is selected; two injected effects
are both selected; a clean scan selects nothing; the raw held-out gap (CONTRACTS §4.1 metric)
falls by at least half and the final held-out gap is within 1.5x the noise level (the gap a
perfect model would leave, from the reported std). Known exception, asserted as such:
detector_aperture and beam_divergence (see KNOWN_BLUR below). Every synthetic-scan diagnosis
here takes 7-30 s, so all are slow tests (``make test-slow``); the default suite runs the same
code on the real Z307 scan (diagnosis, CLI json and report), the twins and the units
(test_diagnose_twins.py, test_diagnose_units.py).
"""
import json

import pytest

from rig.effects import CATALOGUE
from rig.synth import DETECTION_LIMIT_CASES, SCORE_CASES, score_case

CASES = {
    "clean": {},
    "angle_offset": {"angle_offset": SCORE_CASES["angle_offset"]},
    "stray_background": {"stray_background": SCORE_CASES["stray_background"]},
    "detector_aperture": {"detector_aperture": SCORE_CASES["detector_aperture"]},
    "pair": {"angle_offset": SCORE_CASES["angle_offset"], "stray_background": SCORE_CASES["stray_background"]},
}
#: the injected parameter the fit must recover within 10 %
RECOVER = {"angle_offset": "offset_deg", "arm_offset": "offset_deg", "sample_tilt": "tilt_deg",
           "detector_aperture": "width_mm", "beam_divergence": "sigma_mrad", "footprint_overfill": "sample_width_mm",
           "polarization_leakage": "fraction", "stray_background": "level_per_sr",
           "detector_nonlinearity": "saturation_per_sr", "substrate_reflection": "transmittance"}


def run_case(name):
    """One diagnosis per test (each case is used by exactly one test, so pytest-xdist never
    computes a case twice)."""
    return score_case(CASES[name], seed=1, workers=1)


def _check_gap(doc):
    """Acceptance: the raw held-out gap halves and ends within 1.5x the noise level."""
    noise = doc["noise_level"]["heldout_gap"]
    before, after = doc["baseline"]["heldout_gap"], doc["final"]["heldout_gap"]
    assert noise > 0
    assert after <= 1.5 * noise, (after, noise)
    assert after <= 0.5 * before, (before, after)
    return before, after, noise


def _check_contract_fields(doc):
    """CONTRACTS §4.1: the fields and their types."""
    assert doc["gap_metric"] == "rms_log10"
    assert doc["heldout_theta_i_deg"] == [40.0, 80.0]
    assert set(doc["baseline"]) >= {"heldout_gap", "train_gap"}
    assert set(doc["final"]) >= {"heldout_gap", "train_gap"}
    assert {r["name"] for r in doc["regions"]} >= {"specular_core", "shoulder", "wing"}
    for r in doc["regions"]:
        assert set(r) >= {"name", "theta_i_deg", "polarization", "n_points", "heldout", "gap", "bias"}
        assert r["heldout"] == (r["theta_i_deg"] in (40.0, 80.0))
    names = [c["name"] for c in doc["candidates"]]
    assert sorted(names) == sorted(CATALOGUE)  # every effect tried alone
    assert [c["delta_bic"] for c in doc["candidates"]] == sorted(c["delta_bic"] for c in doc["candidates"])
    for c in doc["candidates"]:
        assert set(c) >= {"name", "fitted", "delta_bic", "heldout_gap_before", "heldout_gap_after"}
    json.dumps(doc["candidates"])


def _check_single(doc, name, params):
    assert doc["candidates"][0]["name"] == name
    assert doc["selected_effects"][0] == name
    _check_gap(doc)
    key = RECOVER[name]
    assert doc["selected_parameters"][name][key] == pytest.approx(params[key], rel=0.1)


@pytest.mark.slow
def test_clean_scan_selects_nothing():
    _, _, doc = run_case("clean")
    assert doc["selected_effects"] == []
    noise = doc["noise_level"]["heldout_gap"]
    assert doc["final"]["heldout_gap"] <= 1.5 * noise
    _check_contract_fields(doc)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["angle_offset", "stray_background", "detector_aperture"])
def test_single_effect_is_ranked_first_and_halves_the_gap(name):
    """One effect that moves the specular core (stage offset 0.3 deg), one in the wings (a 2e-3 /sr
    floor), one that blurs the core (a 10 mm slit, which a wider baseline lobe partly imitates):
    ranked first, selected, parameter recovered, raw held-out gap halved."""
    _, _, doc = run_case(name)
    _check_contract_fields(doc)
    _check_single(doc, name, SCORE_CASES[name])


@pytest.mark.slow
def test_two_effects_are_both_selected():
    _, _, doc = run_case("pair")
    assert set(doc["selected_effects"]) == {"angle_offset", "stray_background"}
    _check_gap(doc)


@pytest.mark.slow
def test_cli_writes_json_and_report(tmp_path):
    from materials.scan import write_scan
    from straylight.cli.main import main

    from rig.effects import build_effect
    from rig.points import compact_plan
    from rig.synth import glossy_black, synth_scan

    scan = synth_scan(glossy_black(), compact_plan(), [build_effect("stray_background", **SCORE_CASES["stray_background"])],
                      seed=1, n_samples=1024)
    csv = tmp_path / "scan.csv"
    write_scan(csv, scan)
    out = tmp_path / "out.json"
    rc = main(["rig", "diagnose", str(csv), "--holdout-theta-i", "55", "--effects", "stray_background",
               "--json", str(out), "--report", str(tmp_path / "rep"), "--workers", "1"])
    assert rc == 0
    doc = json.loads(out.read_text())
    assert doc["heldout_theta_i_deg"] == [55.0]
    assert [c["name"] for c in doc["candidates"]] == ["stray_background"]
    assert doc["selected_effects"] == ["stray_background"]
    for f in ("report.md", "index.html", "residuals_s.png", "core_p.png", "gaps.png"):
        assert (tmp_path / "rep" / f).stat().st_size > 0


def test_cli_bad_input_is_one_line(tmp_path, capsys):
    from straylight.cli.main import main

    bad = tmp_path / "bad.csv"
    bad.write_text("wavelength_nm,polarization,theta_i_deg\n532,s,10\n")
    assert main(["rig", "diagnose", str(bad), "--json", str(tmp_path / "o.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("straylight: error:") and "bad.csv" in err and "\n" not in err
    assert main(["rig", "diagnose", str(bad), "--effects", "nope", "--json", str(tmp_path / "o.json")]) == 2


def test_cli_writes_json_and_report_on_the_real_scan(tmp_path):
    """``straylight rig diagnose`` on the real Z307 scan (a CSV): the JSON and every report file."""
    from materials.scan import write_scan
    from materials.z307 import read_z307
    from straylight.cli.main import main

    csv = tmp_path / "z307.csv"
    write_scan(csv, read_z307(dataset="control"))
    out = tmp_path / "out.json"
    rc = main(["rig", "diagnose", str(csv), "--effects", "stray_background", "--json", str(out),
               "--report", str(tmp_path / "rep"), "--workers", "1"])
    assert rc == 0
    doc = json.loads(out.read_text())
    assert doc["heldout_theta_i_deg"] == [30.0, 70.0]
    assert [c["name"] for c in doc["candidates"]] == ["stray_background"]
    for f in ("report.md", "index.html", "gaps.png"):
        assert (tmp_path / "rep" / f).stat().st_size > 0


def test_real_z307_unpolarized_coarse_scan_runs():
    """The real Z307 data (unpolarized, 5 deg steps, matte paint): the diagnosis runs, reports
    regions with a 'u' polarization, and selects no effect pinned at a bound."""
    from materials.z307 import read_z307
    from rig.diagnose import diagnose, to_json

    scan = read_z307(dataset="control")
    doc = to_json(diagnose(scan, workers=1))
    assert {r["polarization"] for r in doc["regions"]} == {"u"}
    assert doc["heldout_theta_i_deg"] == [30.0, 70.0]
    assert doc["baseline"]["heldout_gap"] > 0
    at_bound = {c["name"] for c in doc["candidates"] if c["at_bound"]}
    assert not (set(doc["selected_effects"]) & at_bound)


# ----------------------------------------------------------------------------- slow sweeps

@pytest.mark.slow
@pytest.mark.parametrize("name", [n for n in CATALOGUE if n not in ("angle_offset", "stray_background", "detector_aperture")])
def test_catalogue_sweep_each_effect_ranked_first_and_closed(name):
    """The rest of the catalogue at visible strengths (angle_offset, stray_background and
    detector_aperture are the fast tests above)."""
    _, _, doc = score_case({name: SCORE_CASES[name]}, seed=1, workers=1)
    _check_single(doc, name, SCORE_CASES[name])


@pytest.mark.slow
def test_second_pair_tilt_and_leakage():
    """Alone, the 1 deg tilt is masked by the 7 % leakage (the baseline lobe absorbs the lower
    peak; the tilt fit goes to zero): it is found by the screen after leakage is selected."""
    _, _, doc = score_case({"sample_tilt": SCORE_CASES["sample_tilt"],
                            "polarization_leakage": SCORE_CASES["polarization_leakage"]}, seed=1, workers=1)
    assert set(doc["selected_effects"]) == {"sample_tilt", "polarization_leakage"}
    _check_gap(doc)


# In an in-plane scan of a specular lobe, an incidence spread and a wider slit blur the core
# the same way (beta - beta0 moves by cos(theta_i) alpha or cos(theta_r) u, equal at specular):
# near the detection limit the diagnosis may pick either and must then report the pair confounded.
EXPECTED_CONFOUNDED = {"beam_divergence": "detector_aperture"}


@pytest.mark.slow
@pytest.mark.parametrize("name", CATALOGUE)
def test_detection_limit_each_effect_ranked_first(name):
    """Near the detection limit (held-out gap 1.1-1.7x noise; the gap cannot halve there) the
    injected effect is still ranked first and selected, and the final gap is within 1.5x noise."""
    _, _, doc = score_case({name: DETECTION_LIMIT_CASES[name]}, seed=1, workers=1)
    assert doc["final"]["heldout_gap"] <= 1.5 * doc["noise_level"]["heldout_gap"]
    twin = EXPECTED_CONFOUNDED.get(name)
    if twin and doc["candidates"][0]["name"] == twin:
        assert doc["candidates"][1]["name"] == name
        assert doc["selected_effects"][:1] == [twin]
        assert any(set(c["effects"]) == {name, twin} for c in doc["confounded"])
        return
    assert doc["candidates"][0]["name"] == name
    assert doc["selected_effects"][:1] == [name]


@pytest.mark.slow
@pytest.mark.parametrize("name", ["sample_tilt", "stray_background"])
def test_second_material_z302_sample_a(name):
    """Another truth (the z302_sample_a preset: one sharp lobe, rd 5e-4, deep p minimum near
    Brewster). The tilt case needs the final refit from fresh material starts (without it the
    joint fit stopped at 0.89 deg and 1.8x the noise level)."""
    from rig.synth import truth_material

    _, _, doc = score_case({name: SCORE_CASES[name]}, seed=1, workers=1, material=truth_material("z302_sample_a"))
    _check_single(doc, name, SCORE_CASES[name])


# ----------------------------------------------------------------------------- substrate ghost, offset and background

@pytest.mark.slow
@pytest.mark.parametrize("material", ["z302_sample_a", "z302_sample_b"])
@pytest.mark.parametrize("case", ["substrate", "offset_background"])
def test_z302_substrate_ghost_and_offset_with_background(material, case):
    """Both Z302-like presets, from rig.synth's own implementation (complex
    Snell + textbook Fresnel for the ghost): the substrate ghost alone is named substrate_reflection
    (not polarization_leakage, whose p-dip filling it resembles) and its parameters recovered; a
    stage offset with a stray floor is named angle_offset (not arm_offset) and stray_background."""
    from rig.synth import truth_material

    effects = ({"substrate_reflection": SCORE_CASES["substrate_reflection"]} if case == "substrate" else
               {"angle_offset": SCORE_CASES["angle_offset"], "stray_background": SCORE_CASES["stray_background"]})
    _, _, doc = score_case(effects, seed=1, workers=1, material=truth_material(material))
    assert sorted(doc["selected_effects"]) == sorted(effects)
    for name, params in effects.items():
        key = RECOVER[name]
        assert doc["selected_parameters"][name][key] == pytest.approx(params[key], rel=0.1)
    assert doc["final"]["heldout_gap"] <= 1.5 * doc["noise_level"]["heldout_gap"]
    if case == "offset_background":
        check = next(c for c in doc["twin_checks"] if c["alternative"] == "arm_offset")
        assert check["verdict"].startswith("told apart")
