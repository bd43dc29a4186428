"""`straylight material` (CONTRACTS §4.2 eval; fit, show, z307): outputs, golden values, one-line errors."""
import json

import numpy as np
import pytest

from materials.scan import make_scan, write_scan
from straylight.cli.main import main

# PHYSICS §1 golden table (NIST SCATMECH): lambda 0.532 um, n 1.5, sigma 10 nm, lc 2 um, s 2.6, + R_d 0.03
GOLDEN = {"name": "golden", "wavelength_nm": 532.0, "components": [
    {"type": "lambertian", "rd": 0.03},
    {"type": "k_correlation", "sigma_nm": 10.0, "lc_um": 2.0, "s": 2.6, "n": 1.5}]}


def _run(argv, capsys):
    code = main(argv)
    out = capsys.readouterr()
    return code, out.out, out.err


def _hemisphere_dhr(brdf_of, theta_i, n=600):
    """Independent midpoint quadrature of f cos over the hemisphere (theta_r, phi_r grid)."""
    t = (np.arange(n) + 0.5) * (np.pi / 2) / n
    p = (np.arange(2 * n) + 0.5) * np.pi / n
    T, P = np.meshgrid(t, p, indexing="ij")
    wo = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
    wi = np.tile([-np.sin(theta_i), 0.0, np.cos(theta_i)], (len(wo), 1))
    d_omega = (np.sin(T) * (np.pi / 2 / n) * (np.pi / n)).ravel()
    return float(np.sum(brdf_of(wi, wo) * wo[:, 2] * d_omega))


def test_eval_matches_scatmech_golden_values_and_writes_contract_keys(tmp_path, capsys):
    model = tmp_path / "golden.json"
    model.write_text(json.dumps(GOLDEN))
    out = tmp_path / "out.json"
    code, _, err = _run(["material", "eval", str(model), "--theta-i-deg", "45", "--theta-r-deg", "45", "47", "55",
                         "--polarization", "s", "--json", str(out)], capsys)
    assert code == 0, err
    data = json.loads(out.read_text())
    assert {"brdf_per_sr", "theta_r_deg", "dhr"} <= set(data)
    assert data["theta_r_deg"] == [45.0, 47.0, 55.0]
    np.testing.assert_allclose(data["brdf_per_sr"], [1.70433e-01, 1.21033e-01, 2.02963e-02], rtol=2e-4)
    code, _, _ = _run(["material", "eval", str(model), "--theta-i-deg", "10", "--theta-r-deg", "10", "12", "20",
                       "--polarization", "p", "--json", str(out)], capsys)
    np.testing.assert_allclose(json.loads(out.read_text())["brdf_per_sr"], [1.39687e-01, 7.61502e-02, 1.26139e-02],
                               rtol=2e-4)


@pytest.mark.parametrize("pol", ["s", "u"])
def test_eval_dhr_matches_independent_quadrature(tmp_path, capsys, pol):
    from materials.material import load_material

    model = tmp_path / "m.json"
    model.write_text(json.dumps({"name": "m", "wavelength_nm": 532.0, "components": [
        {"type": "lambertian", "rd": 0.05},
        {"type": "k_correlation", "sigma_nm": 20.0, "lc_um": 0.5, "s": 2.5, "n": 1.5}]}))
    out = tmp_path / "o.json"
    code, _, err = _run(["material", "eval", str(model), "--theta-i-deg", "60", "--theta-r-deg", "0",
                         "--polarization", pol, "--json", str(out)], capsys)
    assert code == 0, err
    dhr = json.loads(out.read_text())["dhr"]
    mat = load_material(model)
    expected = _hemisphere_dhr(lambda wi, wo: mat.brdf(wi, wo, pol), np.radians(60.0))
    assert expected > 0.05  # the lobe adds to the diffuse 0.05
    assert dhr == pytest.approx(expected, rel=2e-3)


def test_eval_preset_and_backscatter_side(tmp_path, capsys):
    out = tmp_path / "z.json"
    code, _, err = _run(["material", "eval", "z307", "--theta-i-deg", "70", "--theta-r-deg", "75", "-20",
                         "--polarization", "u", "--json", str(out)], capsys)
    assert code == 0, err
    f = json.loads(out.read_text())["brdf_per_sr"]
    # real data (materials/data, control set): BRF 1.521307 at 75 deg forward; 0.026721 at 20 deg backscatter
    assert f[0] == pytest.approx(1.521307 / np.pi, rel=0.15)
    assert f[1] == pytest.approx(0.026721 / np.pi, rel=0.1)


@pytest.mark.parametrize("argv, needle", [
    (["material", "eval", "z307", "--theta-i-deg", "30", "--theta-r-deg", "95", "--polarization", "s"], "theta-r-deg"),
    (["material", "eval", "nosuch.json", "--theta-i-deg", "30", "--theta-r-deg", "5", "--polarization", "s"], "nosuch"),
    (["material", "fit", "missing.csv", "-o", "x.json"], "missing.csv"),
])
def test_bad_input_gives_one_line_error(argv, needle, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, _, err = _run(argv, capsys)
    assert code == 2
    assert err.count("\n") == 1 and needle in err and "Traceback" not in err


def test_fit_malformed_csv_names_file_line_column(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("wavelength_nm,polarization,theta_i_deg,theta_r_deg,phi_r_deg,brdf_per_sr,brdf_std_per_sr,n_repeats\n"
                   "532,s,30,30,0,0.1,-0.01,3\n")
    code, _, err = _run(["material", "fit", str(bad), "-o", str(tmp_path / "m.json")], capsys)
    assert code == 2 and str(bad) in err and "line 2" in err and "column 7 (brdf_std_per_sr)" in err


def test_fit_show_round_trip(tmp_path, capsys):
    # a Lambertian-only scan with a NaN reading: the fit returns rd and the file loads back
    tr = np.linspace(-80, 80, 33)
    brdf = np.full(tr.shape, 0.04 / np.pi) * (1 + 0.02 * np.random.default_rng(0).standard_normal(tr.size))
    brdf[3] = np.nan
    scan = make_scan(wavelength_nm=532.0, polarization="u", theta_i_deg=30.0, theta_r_deg=tr, phi_r_deg=0.0,
                     brdf_per_sr=brdf, brdf_std_per_sr=0.02 * 0.04 / np.pi, n_repeats=3)
    csv = write_scan(tmp_path / "scan.csv", scan)
    model, report, png = tmp_path / "fit.json", tmp_path / "report.json", tmp_path / "fit.png"
    code, out, err = _run(["material", "fit", str(csv), "--model", "lambertian", "-o", str(model),
                           "--plot", str(png), "--json", str(report), "--seed", "3"], capsys)
    assert code == 0, err
    assert "lambertian.rd" in out and "rms log10" in out and "rho(theta_i)" in out
    rep = json.loads(report.read_text())
    assert rep["n_excluded"] == 1 and rep["params"]["lambertian.rd"] == pytest.approx(0.04, rel=0.02)
    assert png.stat().st_size > 10_000
    show_png = tmp_path / "show.png"
    code, out, err = _run(["material", "show", str(model), "--plot", str(show_png)], capsys)
    assert code == 0, err
    assert show_png.stat().st_size > 10_000
    rho_line = next(line for line in out.splitlines() if line.strip().startswith("30.0"))
    np.testing.assert_allclose([float(v) for v in rho_line.split()[1:]], rep["params"]["lambertian.rd"], rtol=1e-4)
