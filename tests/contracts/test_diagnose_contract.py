"""CONTRACTS §4.1 ``straylight rig diagnose`` on scans the rig simulator makes here for a new material,
at incidence angles that are not the paper's, with an injected catalogue effect (the golden value:
the injected parameter), without one (no effect must be selected), and unpolarized-only.
"""
import csv
import json
import time

import numpy as np
import pytest

from contract_helpers import assert_one_line_error, write_json

CATALOGUE = ("angle_offset", "arm_offset", "sample_tilt", "detector_aperture", "beam_divergence",
             "footprint_overfill", "polarization_leakage", "stray_background", "detector_nonlinearity",
             "substrate_reflection")
REGION_KEYS = ("name", "theta_i_deg", "polarization", "n_points", "heldout", "gap", "bias")
CANDIDATE_KEYS = ("name", "fitted", "delta_bic", "heldout_gap_before", "heldout_gap_after")
OFFSET_DEG = 0.3
MATERIAL = {"name": "contract_black", "wavelength_nm": 633.0, "components": [
    {"type": "lambertian", "rd": 0.02},
    {"type": "k_correlation", "sigma_nm": 4.0, "lc_um": 25.0, "s": 2.5, "n": 1.6},
    {"type": "k_correlation", "sigma_nm": 30.0, "lc_um": 2.0, "s": 3.2, "n": 1.6, "weight": 0.7}]}


def _grid(ti):
    near = np.arange(-2.0, 2.01, 0.25)
    far = np.arange(0.0, 86.0, 8.0)
    tr = np.unique(np.round(np.concatenate([ti + near, far]), 3))
    return [float(t) for t in tr if 0 <= t <= 85]


@pytest.fixture(scope="module")
def scans(tmp_path_factory):
    """(clean, angle-offset) sim scans at 20, 45, 60 deg, s and p."""
    from straylight.cli.main import main

    d = tmp_path_factory.mktemp("diag")
    mat = write_json(d / "mat.json", MATERIAL)
    plan = write_json(d / "plan.json", {"name": "diag", "n_readings": 3, "polarizations": ["s", "p"],
                                        "incidence": [{"theta_i_deg": t, "theta_r_deg": _grid(t)} for t in (20, 45, 60)]})
    out = {}
    for name, extra in (("clean", []), ("offset", ["--effect", f"angle_offset:offset_deg={OFFSET_DEG}"])):
        csv_path = d / f"{name}.csv"
        assert main(["rig", "scan", "--sim", "--sample", str(mat), "--plan", str(plan), "-o", str(csv_path),
                     "--seed", "21"] + extra) == 0
        out[name] = csv_path
    return out


def _cpu_s():
    import resource

    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _no_nan(token):
    raise AssertionError(f"OUT.json holds {token}, which is not JSON")


def _diagnose(cli, scan, out, *extra):
    rc, _, err = cli("rig", "diagnose", scan, "--json", out, *extra)
    assert rc == 0, err
    doc = json.loads(out.read_text(), parse_constant=_no_nan)  # strict JSON: no NaN / Infinity
    assert doc["gap_metric"] == "rms_log10"
    for part in ("baseline", "final"):
        assert set(doc[part]) >= {"heldout_gap", "train_gap"}
        assert doc[part]["heldout_gap"] >= 0 and doc[part]["train_gap"] >= 0
    assert isinstance(doc["selected_effects"], list)
    return doc


def _check_regions(doc, angles, pols):
    held = set(doc["heldout_theta_i_deg"])
    seen = {}
    for r in doc["regions"]:
        for k in REGION_KEYS:
            assert k in r, f"region lacks {k!r}: {r}"
        assert r["heldout"] == (r["theta_i_deg"] in held)
        assert isinstance(r["n_points"], int) and r["n_points"] >= 0
        if r["n_points"] > 0 and r["gap"] is not None:
            assert r["gap"] >= 0 and abs(r["bias"]) <= r["gap"] + 1e-12  # RMS >= |mean| over the same points
        seen.setdefault((r["theta_i_deg"], r["polarization"]), set()).add(r["name"])
    assert set(seen) == {(t, p) for t in angles for p in pols}
    for names in seen.values():
        assert names >= {"specular_core", "shoulder", "wing"}


def test_injected_angle_offset_found(cli, scans, tmp_path):
    effects = ["angle_offset", "stray_background"]
    doc = _diagnose(cli, scans["offset"], tmp_path / "d.json", "--holdout-theta-i", "45", "--effects", *effects)
    assert doc["heldout_theta_i_deg"] == [45.0]
    _check_regions(doc, (20.0, 45.0, 60.0), ("s", "p"))
    cands = doc["candidates"]
    assert sorted(c["name"] for c in cands) == sorted(effects)  # each tried, alone
    for c in cands:
        for k in CANDIDATE_KEYS:
            assert k in c
        assert isinstance(c["fitted"], dict) and c["fitted"]
        assert c["heldout_gap_before"] == pytest.approx(doc["baseline"]["heldout_gap"])
    bic = [c["delta_bic"] for c in cands]
    assert bic == sorted(bic), "candidates must be best first"
    assert cands[0]["name"] == "angle_offset"
    fitted = cands[0]["fitted"]
    offset = fitted.get("offset_deg", next(iter(fitted.values())))
    assert offset == pytest.approx(OFFSET_DEG, abs=0.05)
    assert doc["selected_effects"][0] == "angle_offset"
    assert doc["final"]["heldout_gap"] < 0.5 * doc["baseline"]["heldout_gap"]


def test_clean_scan_selects_nothing(cli, scans, tmp_path):
    doc = _diagnose(cli, scans["clean"], tmp_path / "d.json", "--effects", "angle_offset", "arm_offset",
                    "stray_background")
    assert doc["selected_effects"] == []
    assert set(doc["heldout_theta_i_deg"]) < {20.0, 45.0, 60.0} and doc["heldout_theta_i_deg"]
    assert len(doc["candidates"]) == 3


def test_nan_negative_inf_rows_do_not_crash(cli, scans, tmp_path):
    """CONTRACTS §2: NaN or negative brdf_per_sr is kept but flagged and must not crash a fit."""
    lines = scans["offset"].read_text().splitlines()
    data = [i for i, ln in enumerate(lines) if ln[:1].isdigit()]
    for i, value in zip(data[3::23], ["nan", "-2e-05", "0", "inf", "-0.0"]):
        cells = lines[i].split(",")
        cells[5] = value
        lines[i] = ",".join(cells)
    bad = tmp_path / "flagged.csv"
    bad.write_text("\n".join(lines) + "\n")
    doc = _diagnose(cli, bad, tmp_path / "d.json", "--effects", "angle_offset")
    assert doc["selected_effects"] == ["angle_offset"]


def test_unpolarized_only_scan(cli, scans, tmp_path):
    """u = mean of s and p for an unpolarized beam; a 'u'-only file must diagnose."""
    lines = scans["clean"].read_text().splitlines()
    meta = [ln for ln in lines if ln.startswith("#")]
    rows = list(csv.DictReader([ln for ln in lines if not ln.startswith("#")]))
    by_key = {}
    for r in rows:
        by_key.setdefault((r["theta_i_deg"], r["theta_r_deg"], r["phi_r_deg"]), {})[r["polarization"]] = r
    out = [meta[0] if meta else "# sample: u", ",".join(rows[0].keys())]
    for (ti, tr, ph), pair in by_key.items():
        s, p = pair["s"], pair["p"]
        f = (float(s["brdf_per_sr"]) + float(p["brdf_per_sr"])) / 2
        sd = 0.5 * float(np.hypot(float(s["brdf_std_per_sr"]), float(p["brdf_std_per_sr"])))
        out.append(f"{s['wavelength_nm']},u,{ti},{tr},{ph},{f!r},{sd!r},{s['n_repeats']}")
    u_scan = tmp_path / "u_only.csv"
    u_scan.write_text("\n".join(out) + "\n")
    doc = _diagnose(cli, u_scan, tmp_path / "d.json", "--effects", "stray_background", "angle_offset")
    _check_regions(doc, (20.0, 45.0, 60.0), ("u",))


def test_diagnose_errors(cli, scans, tmp_path):
    rc, _, err = cli("rig", "diagnose", scans["clean"], "--json", tmp_path / "d.json", "--effects", "gremlins")
    assert_one_line_error(rc, err, "gremlins")
    rc, _, err = cli("rig", "diagnose", scans["clean"], "--json", tmp_path / "d.json", "--holdout-theta-i", "33")
    assert_one_line_error(rc, err, "33")
    rc, _, err = cli("rig", "diagnose", scans["clean"], "--json", tmp_path / "d.json",
                     "--holdout-theta-i", "20", "45", "60")
    assert_one_line_error(rc, err)
    assert not (tmp_path / "d.json").exists()


@pytest.mark.slow
def test_paper_sized_scan_all_candidates_under_a_minute(cli, tmp_path):
    """Six incidence angles (not the paper's), s and p, the paper grid, every catalogue effect."""
    from straylight.cli.main import main

    mat = write_json(tmp_path / "mat.json", MATERIAL)
    plan = write_json(tmp_path / "plan.json", {"name": "big", "n_readings": 3, "polarizations": ["s", "p"],
                                               "incidence": [{"theta_i_deg": t, "grid": "paper"}
                                                             for t in (15, 25, 35, 50, 65, 75)]})
    scan = tmp_path / "big.csv"
    assert main(["rig", "scan", "--sim", "--sample", str(mat), "--plan", str(plan), "-o", str(scan), "--seed", "2",
                 "--effect", "angle_offset:offset_deg=0.3"]) == 0
    t0, c0 = time.perf_counter(), _cpu_s()
    doc = _diagnose(cli, scan, tmp_path / "d.json")
    elapsed, cpu = time.perf_counter() - t0, _cpu_s() - c0
    rc, _, err = cli("rig", "diagnose", scan, "--json", tmp_path / "d2.json", "--effects", "angle_offset",
                     "--report", tmp_path / "rep")
    assert rc == 0, err
    assert any(p.suffix == ".png" for p in (tmp_path / "rep").iterdir())
    assert sorted(c["name"] for c in doc["candidates"]) == sorted(CATALOGUE)
    # "under a minute on 2 cores": at most 120 CPU-seconds (necessary; wall time on this shared
    # machine depends on the other jobs, so it is printed, not asserted)
    print(f"paper-sized diagnosis: {elapsed:.1f} s wall, {cpu:.1f} CPU-s")
    assert cpu < 120.0, f"diagnosis used {cpu:.1f} CPU-s ({elapsed:.1f} s wall)"


def test_catalogue_names_registered():
    """CONTRACTS §3: these names must exist (the default candidate set is the whole catalogue)."""
    from rig.effects import effect_names

    assert set(CATALOGUE) <= set(effect_names())


def test_foreign_scan_normal_to_grazing_with_backscatter(cli, tmp_path):
    """A scan not made by this rig: incidence 0..85 deg, negative theta_r (backscatter), no rig metadata,
    the material's own BRDF with 2 % noise and a 2e-5 1/sr floor. It must diagnose, select nothing."""
    from materials import load_material
    from materials.base import brdf_angles

    mat = load_material(MATERIAL)
    rng = np.random.default_rng(1)
    rows = []
    for pol in "sp":
        for ti in (0.0, 8.0, 22.0, 37.0, 52.0, 85.0):
            trs = np.unique(np.concatenate([np.arange(-89.0, 90.0, 7.0), ti + np.arange(-2.0, 2.01, 0.25)]))
            trs = trs[np.abs(trs) <= 89.5]
            f = np.ravel(brdf_angles(mat, np.radians(ti), np.radians(np.abs(trs)), np.where(trs < 0, np.pi, 0.0), pol))
            v = f * (1 + 0.02 * rng.standard_normal(f.size)) + 2e-5 * rng.standard_normal(f.size)
            rows += [f"633.0,{pol},{ti},{t},0.0,{a!r},{0.02 * b + 2e-5!r},5" for t, a, b in zip(trs, v.tolist(), f.tolist())]
    scan = tmp_path / "foreign.csv"
    scan.write_text("# sample: foreign\n" + ",".join(
        ["wavelength_nm", "polarization", "theta_i_deg", "theta_r_deg", "phi_r_deg", "brdf_per_sr", "brdf_std_per_sr",
         "n_repeats"]) + "\n" + "\n".join(rows) + "\n")
    doc = _diagnose(cli, scan, tmp_path / "d.json", "--effects", "angle_offset", "stray_background",
                    "footprint_overfill")
    _check_regions(doc, (0.0, 8.0, 22.0, 37.0, 52.0, 85.0), ("s", "p"))
    assert doc["selected_effects"] == []
    assert doc["baseline"]["heldout_gap"] < 0.05  # 2 % noise is 0.009 dex
