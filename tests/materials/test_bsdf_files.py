"""Zemax / FRED tabulated BSDF files in and out (CONTRACTS §5.2; materials.bsdf_files, materials.bsdf_table).

Real files: ua-loft/bsdf-tools (MIT), tests/data/bsdf/LICENSES.md. Golden values:
- nodes: the files' own numbers;
- DHR: the file's BSDF x cos integrated independently of the model, by the trapezoid rule over the
  file's own grid (Zemax: d Omega = sin R dR dA about the specular pole, nodes below the horizon
  count 0; FRED: d Omega = sin theta d theta d f about the normal);
- Lambertian export: rd / pi and TIS rd (analytic).
"""
from __future__ import annotations

import gzip
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from materials.bsdf_files import BsdfFileError, detect, import_file, parse_zemax, read_text
from materials.base import MaterialError
from straylight.cli.main import main

DATA = Path(__file__).resolve().parents[1] / "data" / "bsdf"
ZEMAX = ["AnoBlackEC1onAlum.bsdf", "ValidationTest_of_TIS_via_BrownVinyl.bsdf", "aeroglaze.bsdf"]
FRED = ["AnoBlackEC1onAlum.txt", "AnoBlackEC1onAlum_fullAz.txt", "aeroglaze_bsdf_final.txt",
        "aeroglaze_20260608_vnir_validation_test_630o79nm.txt"]


@pytest.fixture(scope="module")
def imx455(tmp_path_factory):
    """The Asymmetrical4D image-sensor file (stored gzipped here), imported once."""
    path = tmp_path_factory.mktemp("imx") / "IMX455.bsdf"
    path.write_bytes(gzip.decompress((DATA / "IMX455.bsdf.gz").read_bytes()))
    material, report = import_file(path)
    return path, material, report


def _run(*argv):
    return main([str(a) for a in argv])


def _eval(tmp_path, material_json, theta_i, theta_r, rotation=None):
    out = tmp_path / "eval.json"
    extra = [] if rotation is None else ["--rotation-deg", rotation]
    assert _run("material", "eval", material_json, "--theta-i-deg", theta_i, "--theta-r-deg", *theta_r,
                "--polarization", "u", "--json", out, *extra) == 0
    return json.loads(out.read_text())


def _zemax_grid(path):
    """(aoi, az, rad, data[rot, aoi, az, rad]) read straight from the text (independent of the importer)."""
    lines = read_text(path).splitlines()

    def values(key):
        for i, line in enumerate(lines):
            tok = line.split()
            if tok and tok[0] == key:
                return [float(v) for v in lines[i + 1].split()]

    aoi, az, rad = values("AngleOfIncidence"), values("ScatterAzimuth"), values("ScatterRadial")
    start = next(i for i, line in enumerate(lines) if line.startswith("DataBegin"))
    nums = []
    for line in lines[start + 1:]:
        tok = line.split()
        if not tok or tok[0] == "TIS":
            continue
        if tok[0] == "DataEnd":
            break
        nums += [float(v) for v in tok]
    return aoi, az, rad, np.asarray(nums).reshape(-1, len(aoi), len(az), len(rad))


# ------------------------------------------------------------------------------------ recognition


@pytest.mark.parametrize("name", ZEMAX + FRED)
def test_every_zemax_and_fred_file_imports(name, tmp_path):
    out = tmp_path / "m.json"
    assert _run("material", "import", DATA / name, "-o", out) == 0
    data = json.loads(out.read_text())
    (comp,) = data["components"]
    assert comp["type"] == "bsdf_table"
    assert detect(read_text(DATA / name)) == ("zemax" if name in ZEMAX else "fred")


def test_recognised_by_content_not_extension(tmp_path):
    fred_as_bsdf = tmp_path / "looks_like_zemax.bsdf"
    fred_as_bsdf.write_text((DATA / "AnoBlackEC1onAlum.txt").read_text())
    _, report = import_file(fred_as_bsdf)
    assert report["format"] == "fred"


def test_speos_and_other_files_refused_in_one_line(tmp_path, capsys):
    assert _run("material", "import", DATA / "test_speos.rtd", "-o", tmp_path / "x.json") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Speos" in err[0] and "not supported" in err[0]
    junk = tmp_path / "notes.bsdf"
    junk.write_text("hello\nworld\n")
    assert _run("material", "import", junk, "-o", tmp_path / "y.json") == 2
    assert "nor a FRED" in capsys.readouterr().err
    assert not (tmp_path / "x.json").exists()


def test_truncated_zemax_file_names_the_count(tmp_path):
    text = (DATA / "AnoBlackEC1onAlum.bsdf").read_text().splitlines()
    bad = tmp_path / "cut.bsdf"
    bad.write_text("\n".join(text[:-5]))
    with pytest.raises(BsdfFileError, match="expected 4 blocks x 19 azimuths x 12 radial"):
        import_file(bad)


# ------------------------------------------------------------------------------------ nodes


@pytest.mark.parametrize("name", ["AnoBlackEC1onAlum.bsdf", "test_nan.bsdf"])
def test_zemax_in_plane_nodes_come_back_from_eval(name, tmp_path):
    """Every in-plane node with a value (test_nan.bsdf: NaN nodes have none) within 1e-3."""
    path = DATA / name
    out = tmp_path / "m.json"
    assert _run("material", "import", path, "-o", out) == 0
    aoi, az, rad, data = _zemax_grid(path)
    for j, ti in enumerate(aoi):
        # azimuth 0: toward the normal (theta_r = ti - R, negative = backscatter side); 180: away
        thr, want = [], []
        for a_idx, sign in ((az.index(0.0), -1.0), (az.index(180.0), 1.0)):
            for k, r in enumerate(rad):
                t = ti + sign * r
                if -89.0 <= t <= 89.0 and not np.isnan(data[0, j, a_idx, k]):
                    thr.append(t)
                    want.append(data[0, j, a_idx, k])
        got = _eval(tmp_path, out, ti, thr)["brdf_per_sr"]
        np.testing.assert_allclose(got, want, rtol=1e-3, atol=1e-9, err_msg=f"incidence {ti}")


@pytest.mark.parametrize("name", ["AnoBlackEC1onAlum_fullAz.txt", "aeroglaze_bsdf_final.txt",
                                  "aeroglaze_20260608_vnir_validation_test_630o79nm.txt"])
def test_fred_in_plane_nodes_come_back_from_eval(name, tmp_path):
    path = DATA / name
    out = tmp_path / "m.json"
    assert _run("material", "import", path, "-o", out) == 0
    blocks: dict = {}
    for line in path.read_text().splitlines()[2:]:
        tok = [float(v) for v in line.split()]
        if len(tok) == 2:
            cur = blocks.setdefault(tok[0], {})
        elif tok[1] in (0.0, 180.0):  # in the plane of incidence
            cur[tok[0] if tok[1] == 0.0 else -tok[0]] = tok[2]
    for ti, rows in blocks.items():
        thr = sorted(rows)
        got = _eval(tmp_path, out, ti, thr)["brdf_per_sr"]
        np.testing.assert_allclose(got, [rows[t] for t in thr], rtol=1e-3, atol=1e-9, err_msg=f"incidence {ti}")


# ------------------------------------------------------------------------------------ DHR


def _zemax_trapezoid_dhr(path):
    aoi, az, rad, data = _zemax_grid(path)
    a, r = np.meshgrid(np.radians(az), np.radians(rad), indexing="ij")
    out = []
    for j, ti in enumerate(aoi):
        t = math.radians(ti)
        cos_r = np.cos(r) * math.cos(t) + np.sin(r) * np.cos(a) * math.sin(t)  # node's cos theta_r
        integrand = np.where(cos_r > 0, data[0, j] * cos_r, 0.0) * np.sin(r)
        out.append(2.0 * np.trapezoid(np.trapezoid(integrand, np.radians(rad), axis=1), np.radians(az)))
    return aoi, np.asarray(out)


@pytest.mark.parametrize("name", ["AnoBlackEC1onAlum.bsdf", "ValidationTest_of_TIS_via_BrownVinyl.bsdf"])
def test_zemax_dhr_matches_an_independent_trapezoid(name, tmp_path):
    """Trapezoid over the file's own (azimuth, radial) grid, x2 for the mirrored half (PlaneSymmetrical).
    The model interpolates log10 between nodes (the trapezoid: linear) and cuts at the true horizon,
    so they agree to the grid's own resolution (8 %); the file's TIS line is not this quantity."""
    aoi, want = _zemax_trapezoid_dhr(DATA / name)
    _, report = import_file(DATA / name)
    np.testing.assert_allclose(report["dhr"][0], want, rtol=0.08)
    out = tmp_path / "m.json"
    assert _run("material", "import", DATA / name, "-o", out) == 0
    assert _eval(tmp_path, out, aoi[1], [0.0])["dhr"] == pytest.approx(report["dhr"][0][1], rel=1e-3)


def test_fred_dhr_matches_an_independent_trapezoid():
    """FRED full-azimuth grid: trapezoid in (theta, f) about the normal, with sin theta cos theta; the
    outermost ring (80 deg) held to the horizon as the model holds it."""
    path = DATA / "AnoBlackEC1onAlum_fullAz.txt"
    blocks: dict = {}
    for line in path.read_text().splitlines()[2:]:
        tok = [float(v) for v in line.split()]
        if len(tok) == 2:
            cur = blocks.setdefault(tok[0], [])
        else:
            cur.append(tok)
    want = []
    for ti, rows in blocks.items():
        rows = np.asarray(rows)
        th = np.unique(rows[:, 0])
        f = np.unique(rows[rows[:, 0] > 0, 1])
        grid = np.zeros((len(th) + 1, len(f) + 1))
        for t, p, v in rows:
            i = np.searchsorted(th, t)
            if t == 0:
                grid[i, :] = v
            else:
                grid[i, np.searchsorted(f, p)] = v
        grid[:, -1] = grid[:, 0]
        grid[-1] = grid[-2]
        thr = np.radians(np.append(th, 90.0))
        integrand = grid * (np.sin(thr) * np.cos(thr))[:, None]
        want.append(np.trapezoid(np.trapezoid(integrand, np.radians(np.append(f, 360.0)), axis=1), thr))
    _, report = import_file(path)
    assert list(blocks) == report["theta_i_deg"]
    np.testing.assert_allclose(report["dhr"][0], want, rtol=0.08)


def test_tis_lines_reported_not_used(tmp_path):
    _, report = import_file(DATA / "AnoBlackEC1onAlum.bsdf")
    assert report["tis_in_file"] == [0.038655, 0.039136, 0.047596, 0.106539]
    assert abs(report["dhr"][0][0] - 0.038655) > 0.005  # a different definition; values not rescaled to it


def test_a_tis_line_without_its_value_keeps_the_later_ones_in_place(tmp_path):
    """Three blocks whose middle TIS line has no value: the third block's TIS stays the third's (null for the
    second, in strict JSON), not moved to the second incidence."""
    text = _zemax_text([0, 20, 50], [0.01, 0.01, 0.01]).split("\n")
    tis_lines = [i for i, line in enumerate(text) if line.startswith("TIS")]
    text[tis_lines[0]], text[tis_lines[1]], text[tis_lines[2]] = "TIS\t0.123", "TIS", "TIS\t0.456"
    f = tmp_path / "gap.bsdf"
    f.write_text("\n".join(text))
    _, report = import_file(f)
    assert report["tis_in_file"] == [0.123, None, 0.456]
    out = tmp_path / "gap.json"
    assert _run("material", "import", f, "-o", out) == 0
    assert json.loads(out.read_text())["components"][0]["tis"] == [0.123, None, 0.456]


# ------------------------------------------------------------------------------------ refusals


def _zemax_text(aoi, values_per_aoi, radial=(0, 10, 20, 30, 40, 50, 60, 70, 80, 90)):
    az = list(range(0, 181, 30))
    lines = ["Source\tMeasured", "Symmetry\tPlaneSymmetrical", "SpectralContent\tMonochrome", "ScatterType\tBRDF",
             "SampleRotation\t1", "0", f"AngleOfIncidence\t{len(aoi)}", "\t".join(map(str, aoi)),
             f"ScatterAzimuth\t{len(az)}", "\t".join(map(str, az)), f"ScatterRadial\t{len(radial)}",
             "\t".join(map(str, radial)), "Monochrome", "DataBegin"]
    for v in values_per_aoi:
        lines.append("TIS\t0.5")
        lines += ["\t".join([f"{v:.6e}"] * len(radial))] * len(az)
    lines.append("DataEnd")
    return "\n".join(lines) + "\n"


def test_non_physical_file_refused_naming_the_incidence(tmp_path, capsys):
    bad = tmp_path / "hot.bsdf"
    bad.write_text(_zemax_text([10, 40, 70], [0.05, 0.5, 0.05]))  # 0.5/sr x pi > 1 at 40 deg
    assert _run("material", "import", bad, "-o", tmp_path / "hot.json") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not physical" in err[0] and "incidence 40 deg" in err[0] and "never rescaled" in err[0]
    assert not (tmp_path / "hot.json").exists()


def test_spike_between_incidence_nodes_does_not_pass(tmp_path):
    """A tabulated material whose node at 62.5 deg (off the 1-deg grid) is a spike."""
    from materials.material import material_from_dict

    ti = [60.0, 62.5, 65.0]
    tr = list(np.linspace(-85, 85, 35))
    rows = [[0.01] * len(tr), [100.0] * len(tr), [0.01] * len(tr)]
    with pytest.raises(MaterialError, match="62.5 deg"):
        material_from_dict({"name": "spike", "components": [
            {"type": "tabulated", "theta_i_deg": ti, "theta_r_deg": tr, "brdf_per_sr": rows}]})
    spike = {"type": "bsdf_table", "theta_i_deg": ti, "blocks": [
        {"theta_r_deg": [0.0, 30.0, 60.0, 30.0], "phi_r_deg": [0.0, 0.0, 0.0, 90.0], "bsdf_per_sr": [v] * 4}
        for v in (0.01, 100.0, 0.01)]}
    with pytest.raises(MaterialError, match="incidence 62.5 deg"):
        material_from_dict({"name": "spike2", "components": [spike]})


# ------------------------------------------------------------------------------------ export


def test_lambertian_exports_rd_over_pi_with_tis_rd(tmp_path):
    mat = tmp_path / "lam.json"
    mat.write_text(json.dumps({"name": "lam", "components": [{"type": "lambertian", "rd": 0.03}]}))
    out = tmp_path / "lam.bsdf"
    assert _run("material", "export", mat, "--format", "zemax", "-o", out) == 0
    text = out.read_text()
    assert "Symmetry\tPlaneSymmetrical" in text
    aoi, az, rad, data = _zemax_grid(out)
    tis = [float(line.split()[1]) for line in text.splitlines() if line.startswith("TIS")]
    np.testing.assert_allclose(tis, 0.03, rtol=1e-5)
    a, r = np.meshgrid(np.radians(az), np.radians(rad), indexing="ij")
    for j, ti in enumerate(aoi):
        t = math.radians(ti)
        cos_r = np.cos(r) * math.cos(t) + np.sin(r) * np.cos(a) * math.sin(t)
        above = cos_r > -1e-9  # a node on the horizon carries the limit from above: rd / pi too
        np.testing.assert_allclose(data[0, j][above], 0.03 / math.pi, rtol=1e-6)
        assert np.all(data[0, j][~above] == 0.0)
    fred = tmp_path / "lam.txt"
    assert _run("material", "export", mat, "--format", "fred", "-o", fred) == 0
    vals = [float(line.split()[2]) for line in fred.read_text().splitlines()[2:] if len(line.split()) == 3]
    np.testing.assert_allclose(vals, 0.03 / math.pi, rtol=1e-6)


@pytest.mark.parametrize("fmt", ["zemax", "fred"])
def test_fitted_model_export_import_round_trip(fmt, tmp_path):
    """The preset z302_sample_b (a fit of the paper's model) written and read back: in-plane within 5 %."""
    from materials.base import brdf_angles
    from materials.material import load_material

    out = tmp_path / f"z302.{fmt}"
    assert _run("material", "export", "z302_sample_b", "--format", fmt, "-o", out) == 0
    back = tmp_path / "back.json"
    assert _run("material", "import", out, "-o", back) == 0
    orig = load_material("z302_sample_b")
    for ti in (10.0, 30.0, 60.0):
        thr = np.array([-70, -40, -10, 0, 5, 20, ti - 3, ti - 1, ti + 1, ti + 3, 50, 75], float)
        thr = thr[np.abs(thr) < 89]
        want = brdf_angles(orig, math.radians(ti), np.radians(np.abs(thr)), np.where(thr >= 0, 0, np.pi))
        got = _eval(tmp_path, back, ti, thr)["brdf_per_sr"]
        np.testing.assert_allclose(got, want, rtol=0.05, err_msg=f"{fmt} incidence {ti}")


def test_export_of_imported_table_is_readable_again(tmp_path):
    src = DATA / "AnoBlackEC1onAlum.bsdf"
    mat = tmp_path / "m.json"
    assert _run("material", "import", src, "-o", mat) == 0
    out = tmp_path / "again.bsdf"
    assert _run("material", "export", mat, "--format", "zemax", "--aoi-deg", "10", "30", "50", "70",
                "--radial-deg", "0", "5", "10", "15", "20", "30", "40", "50", "60", "70", "80", "90", "-o", out) == 0
    _, az0, rad0, data0 = _zemax_grid(src)
    _, az1, rad1, data1 = _zemax_grid(out)
    assert rad0 == rad1
    # the original nodes at the exported azimuths come back (0 and 180 are on both grids)
    aoi = [10.0, 30.0, 50.0, 70.0]
    for a in (0.0, 180.0):
        for j, ti in enumerate(aoi):  # nodes above the horizon (on it, export writes the limit from above)
            t, ca = math.radians(ti), math.cos(math.radians(a))
            cz = np.cos(np.radians(rad0)) * math.cos(t) + np.sin(np.radians(rad0)) * ca * math.sin(t)
            above = cz > 1e-6
            np.testing.assert_allclose(data1[0, j, az1.index(a)][above], data0[0, j, az0.index(a)][above],
                                       rtol=1e-3, atol=1e-9)


# ------------------------------------------------------------------------------------ anisotropic


def test_anisotropic_nodes_by_rotation(imx455, tmp_path):
    """IMX455 (Asymmetrical4D): the nodes of rotations 0, 30 and 90 come back at those rotations, on
    both sides of the specular direction; the scatter changes with the rotation as the file says."""
    from materials.base import brdf_angles
    from materials.bsdf_table import rotated

    path, material, report = imx455
    assert report["symmetry"] == "none" and len(report["rotation_deg"]) == 37
    aoi, az, rad, data = _zemax_grid(path)
    rots = report["rotation_deg"]
    ti = 30.0
    j = aoi.index(ti)
    for rot in (0.0, 30.0, 90.0):
        r = rots.index(rot)
        thr, want = [], []
        for k, rr in enumerate(rad):
            for a_deg, sign in ((0.0, -1.0), (180.0, 1.0)):
                t = ti + sign * rr
                if -85 <= t <= 85 and rr > 0:
                    thr.append(t)
                    want.append(data[r, j, az.index(a_deg), k])
        thr = np.asarray(thr)
        got = brdf_angles(rotated(material, rot), math.radians(ti), np.radians(np.abs(thr)),
                          np.where(thr >= 0, 0.0, np.pi))
        np.testing.assert_allclose(got, want, rtol=1e-3, atol=1e-9, err_msg=f"rotation {rot}")
    # out of plane too (azimuth 90 of the file: -y of the incidence frame)
    k = rad.index(20.0)
    th, ph = np.radians(ti), np.radians(20.0)
    wo = np.array([[math.cos(ph) * math.sin(th), -math.sin(ph), math.cos(ph) * math.cos(th)]])
    wi = np.array([[-math.sin(th), 0.0, math.cos(th)]])
    got = rotated(material, 30.0).brdf(wi, wo)[0]
    assert got == pytest.approx(data[rots.index(30.0), j, az.index(90.0), k], rel=1e-3)
    # a visible change with rotation
    a = brdf_angles(rotated(material, 30.0), math.radians(ti), np.radians([10.0, 10.0, 50.0]),
                    np.array([np.pi, 0.0, 0.0]))
    b = brdf_angles(rotated(material, 90.0), math.radians(ti), np.radians([10.0, 10.0, 50.0]),
                    np.array([np.pi, 0.0, 0.0]))
    assert not np.allclose(a, b, rtol=0.05)


def test_eval_rotation_option_on_a_small_asymmetrical4d_file(tmp_path):
    """Two sample rotations (0: 0.01/sr, 90: 0.03/sr everywhere): eval --rotation-deg gives each, and
    their geometric blend half-way (45 deg); periodically from 90 back to 360 = 0 beyond the last rotation."""
    az = list(range(0, 360, 45))
    rad = [0, 20, 40, 60, 80, 100, 120, 140, 160, 180]
    lines = ["Source\tMeasured", "Symmetry\tAsymmetrical4D", "SpectralContent\tMonochrome", "ScatterType\tBRDF",
             "SampleRotation\t2", "0\t90", "AngleOfIncidence\t2", "10\t50", f"ScatterAzimuth\t{len(az)}",
             "\t".join(map(str, az)), f"ScatterRadial\t{len(rad)}", "\t".join(map(str, rad)), "Monochrome",
             "DataBegin"]
    for v in (0.01, 0.01, 0.03, 0.03):
        lines += ["\t".join([str(v)] * len(rad))] * len(az)
    lines.append("DataEnd")
    src = tmp_path / "aniso.bsdf"
    src.write_text("\n".join(lines) + "\n")
    mat = tmp_path / "aniso.json"
    assert _run("material", "import", src, "-o", mat) == 0
    for rot, want in ((0.0, 0.01), (90.0, 0.03), (45.0, math.sqrt(3e-4)), (225.0, math.sqrt(3e-4)),
                      (180.0, 0.03 ** (2 / 3) * 0.01 ** (1 / 3))):
        got = _eval(tmp_path, mat, 30.0, [-40.0, 0.0, 30.0, 60.0], rotation=rot)
        np.testing.assert_allclose(got["brdf_per_sr"], want, rtol=1e-9, err_msg=str(rot))
        assert got["dhr"] == pytest.approx(want * math.pi, rel=2e-3)


def test_zemax_missing_value_lines_use_defaults():
    comp = parse_zemax((DATA / "aeroglaze.bsdf").read_text(), "aeroglaze.bsdf")
    assert comp["rotation_deg"] == [0.0] and comp["theta_i_deg"] == [10.0, 30.0, 50.0, 70.0]
    assert comp["symmetry"] == "plane"


# ------------------------------------------------------------------------------------ fit


def test_fit_accepts_a_tabulated_file_as_the_measurement(tmp_path, capsys):
    """The paper's model fitted to ua-loft's Zemax file (650 nm from its comment line), with uncertainties."""
    out = tmp_path / "fit.json"
    report = tmp_path / "fit_report.json"
    assert _run("material", "fit", DATA / "AnoBlackEC1onAlum.bsdf", "-o", out, "--starts", "1",
                "--json", report) == 0
    text = capsys.readouterr().out
    assert "in-plane nodes at 10, 30, 50, 70 deg, 650 nm" in text and "+-" in text
    fitted = json.loads(out.read_text())
    assert fitted["wavelength_nm"] == 650.0
    assert {c["type"] for c in fitted["components"]} == {"lambertian", "k_correlation"}
    # FRED in-plane file: no wavelength stated -> a one-line error naming the option, then with it
    assert _run("material", "fit", DATA / "aeroglaze_bsdf_final.txt", "-o", tmp_path / "a.json", "--starts", "1") == 2
    assert "--wavelength-nm" in capsys.readouterr().err
    assert _run("material", "fit", DATA / "aeroglaze_bsdf_final.txt", "-o", tmp_path / "a.json", "--starts", "1",
                "--wavelength-nm", "632.8") == 0


def test_importance_sampling_is_unbiased_for_an_imported_table():
    """Mean sample weight (f cos / pdf) equals the quadrature DHR: the draws cover the table."""
    material = import_file(DATA / "AnoBlackEC1onAlum.bsdf")[0]
    table = material.components[0]
    rng = np.random.default_rng(3)
    for ti in (10.0, 70.0):
        t = math.radians(ti)
        n = 200_000
        wi = np.tile([-math.sin(t), 0.0, math.cos(t)], (n, 1))
        smp = table.sample(wi, rng.random((n, 3)))
        mean, err = smp.weight.mean(), smp.weight.std() / math.sqrt(n)
        assert abs(mean - float(table.dhr([ti])[0])) < 4 * err + 1e-4, (ti, mean, err)


# ------------------------------------------------------------------------------------ format variants


def test_fred_sin_log_scale_comma_variant(tmp_path):
    """angles=sin (a = sin f sin theta, b = cos f sin theta), bsdf=log, scale=2, comma separated."""
    path = tmp_path / "variant.dat"
    rows = [(0.0, -0.6, -2.0), (0.0, -0.2, -2.2), (0.0, 0.5, -1.0), (0.0, 0.7, -1.5), (0.3, 0.5, -1.8), (-0.3, 0.5, -1.8)]
    path.write_text("type bsdf_data\nformat angles=sin bsdf=log scale=2 exclude=0.03\n0,0.5\n"
                    + "\n".join(f"{a},{b},{v}" for a, b, v in rows) + "\n")
    material, report = import_file(path)
    assert report["format"] == "fred" and report["theta_i_deg"] == [pytest.approx(30.0)]
    from materials.base import directions_from_angles

    for a, b, v in rows:
        theta_r = math.asin(math.hypot(a, b))
        phi_r = math.atan2(a, b)
        wi, wo = directions_from_angles(math.radians(30.0), theta_r, phi_r)
        assert material.brdf(wi, wo)[0] == pytest.approx(2.0 * 10.0**v, rel=1e-9)


def test_zemax_btdf_asymmetrical_variant(tmp_path):
    """A BTDF in an Asymmetrical (full-azimuth) file: imported as scatter 'btdf'; its hemisphere
    integral is the transmittance (uniform 0.05/sr: 0.05 pi, analytic)."""
    az = list(range(0, 360, 30))
    rad = list(range(0, 181, 10))
    lines = ["Source  Measured", "Symmetry  Asymmetrical", "SpectralContent  Monochrome", "ScatterType  BTDF",
             "SampleRotation  1", "0", "AngleOfIncidence  2", "0  40", f"ScatterAzimuth  {len(az)}",
             "  ".join(map(str, az)), f"ScatterRadial  {len(rad)}", "  ".join(map(str, rad)), "", "Monochrome",
             "DataBegin"]
    for _ in range(2):
        lines.append("TIS  0.157")
        lines += ["  ".join(["5.000E-02"] * len(rad))] * len(az)
    lines.append("DataEnd")
    path = tmp_path / "diffuser.bsdf"
    path.write_text("\n".join(lines) + "\n")
    material, report = import_file(path)
    assert report["scatter"] == "btdf" and report["symmetry"] == "none"
    np.testing.assert_allclose(report["dhr"][0], 0.05 * math.pi, rtol=2e-3)
    text = _run_export_text(tmp_path, material)
    assert "ScatterType\tBTDF" in text


def _run_export_text(tmp_path, material):
    from materials.material import save_material

    mat = tmp_path / "m.json"
    save_material(mat, material, check_energy=False)
    out = tmp_path / "out.bsdf"
    assert _run("material", "export", mat, "--format", "zemax", "-o", out) == 0
    return out.read_text()


def test_fred_rows_on_the_horizon_are_dropped(tmp_path):
    path = tmp_path / "edge.txt"
    path.write_text("type bsdf_data\nformat angles=deg bsdf=value scale=1\n20\t0\n-90\t0\t0.5\n-45\t0\t0.01\n"
                    "0\t0\t0.02\n20\t0\t0.05\n60\t0\t0.01\n90\t0\t0.5\n")
    material, report = import_file(path)
    assert report["theta_i_deg"] == [20.0]
    assert len(material.components[0].blocks[0]["bsdf_per_sr"]) == 4


# ------------------------------------------------------------------------------------ as other writers write them


@pytest.mark.parametrize("encoding", ["utf-16", "utf-16-le", "utf-16-be"])
def test_utf16_crlf_files_read_as_the_utf8_file(encoding, tmp_path):
    """Windows programs save "Unicode" text: UTF-16 with a byte-order mark or without one, CRLF.
    The same numbers come out as from the UTF-8 original (Zemax and FRED)."""
    from materials.bsdf_files import parse_fred

    for name, parse in (("AnoBlackEC1onAlum.bsdf", parse_zemax), ("aeroglaze_bsdf_final.txt", parse_fred)):
        path = tmp_path / name
        path.write_bytes((DATA / name).read_text().replace("\n", "\r\n").encode(encoding))
        assert parse(read_text(path)) == parse(read_text(DATA / name))
    assert _run("material", "import", tmp_path / "AnoBlackEC1onAlum.bsdf", "-o", tmp_path / "m.json") == 0


def test_comment_and_blank_lines_between_a_count_and_its_values():
    """'Any line that starts with # is ignored' (the format's own rule), blank lines likewise,
    wherever they sit: between a count line and its value line too."""
    text = (DATA / "AnoBlackEC1onAlum.bsdf").read_text()
    spaced = re.sub(r"^(SampleRotation|AngleOfIncidence|ScatterAzimuth|ScatterRadial)(\t\d+)$",
                    r"\1\2\n# values follow\n\n", text, flags=re.M)
    assert spaced.count("# values follow") == 4
    assert parse_zemax(spaced) == parse_zemax(text)


def test_nan_nodes_are_left_out_and_reported(tmp_path, capsys):
    """ua-loft's test.bsdf marks unmeasured nodes NaN (699 below the horizon, 59 above): imported,
    the 59 reported; a block with no value at all is refused naming its incidence."""
    assert _run("material", "import", DATA / "test_nan.bsdf", "-o", tmp_path / "m.json") == 0
    assert "note: 59 nodes above the horizon hold NaN" in capsys.readouterr().out
    empty = tmp_path / "empty.bsdf"
    empty.write_text(_zemax_text([10, 40], [0.05, float("nan")]))
    assert _run("material", "import", empty, "-o", tmp_path / "e.json") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no value above the horizon" in err[0] and "incidence 40 deg" in err[0]
    fred = tmp_path / "nan.txt"
    fred.write_text("type bsdf_data\nformat angles=deg bsdf=value scale=1\n20\t0\n-40\t0\t0.02\n0\t0\tNaN\n"
                    "20\t0\t0.05\n60\t0\t0.01\n")
    material, report = import_file(fred)
    assert report["notes"] == ["1 rows hold NaN (no measurement) and are left out"]
    assert len(material.components[0].blocks[0]["bsdf_per_sr"]) == 3


def test_closing_rotation_that_disagrees_is_reported(imx455):
    """IMX455's rotation 360 is not its rotation 0 but that block mirrored in azimuth: the import says so."""
    _, _, report = imx455
    (note,) = report["notes"]
    assert "rotation 360 deg repeats rotation 0 deg" in note and "mirrored in azimuth" in note


def test_count_mismatch_names_the_block_or_the_line(tmp_path):
    lines = (DATA / "AnoBlackEC1onAlum.bsdf").read_text().splitlines()
    second = [k for k, line in enumerate(lines) if line.startswith("TIS")][1]
    short = list(lines)
    short[second + 3] = "\t".join(short[second + 3].split("\t")[:-1])
    bad = tmp_path / "short.bsdf"
    bad.write_text("\n".join(short) + "\n")
    with pytest.raises(BsdfFileError, match=rf"block from line {second + 1} \(rotation 0 deg, incidence 30 deg\) holds 227"):
        import_file(bad)
    no_tis = [line for line in short if not line.startswith("TIS")]
    bad.write_text("\n".join(no_tis) + "\n")
    with pytest.raises(BsdfFileError, match=r"line \d+ holds 11 values, not one per radial angle \(12\)"):
        import_file(bad)
    begin = lines.index("DataBegin")
    commas = lines[:begin + 1] + [line.replace(".", ",") for line in lines[begin + 1:]]
    bad.write_text("\n".join(commas) + "\n")
    with pytest.raises(BsdfFileError, match="decimal commas"):
        import_file(bad)


def test_a_real_file_above_the_energy_rule_is_refused(tmp_path, capsys):
    """A reflectance standard written as BRDF 0.34 /sr (DHR 1.07): refused in one line naming the incidence."""
    assert _run("material", "import", DATA / "test_blacklab_dev_1243o53nm.txt", "-o", tmp_path / "x.json") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not physical" in err[0] and "incidence 12 deg" in err[0]
    assert not (tmp_path / "x.json").exists()


def test_incidences_in_descending_order_read_as_ascending(tmp_path):
    """The format does not order its lists: the same blocks listed 70, 50, 30, 10 give the same table;
    an incidence listed twice is refused in one line."""
    lines = (DATA / "AnoBlackEC1onAlum.bsdf").read_text().splitlines()
    begin, end = lines.index("DataBegin"), lines.index("DataEnd")
    tis = [k for k in range(begin, end) if lines[k].startswith("TIS")] + [end]
    blocks = [lines[tis[k]:tis[k + 1]] for k in range(4)]
    head = list(lines[:begin + 1])
    k = head.index("AngleOfIncidence\t4") + 1
    head[k] = "70\t50\t30\t10"
    reversed_text = "\n".join(head + sum(blocks[::-1], []) + ["DataEnd"]) + "\n"
    assert parse_zemax(reversed_text) == parse_zemax("\n".join(lines) + "\n")
    head[k] = "10\t30\t30\t70"
    with pytest.raises(BsdfFileError, match="AngleOfIncidence lists 30 deg more than once"):
        parse_zemax("\n".join(head + sum(blocks, []) + ["DataEnd"]) + "\n")


@pytest.mark.parametrize("name", ["AnoBlackEC1onAlum.bsdf", "ValidationTest_of_TIS_via_BrownVinyl.bsdf", "test_nan.bsdf"])
def test_every_zemax_node_above_the_horizon_comes_back(name):
    """Out of plane too: each node's direction from the format's definition (cos R s + sin R (cos A e1
    + sin A e2), e1 toward the normal, e2 = s x e1), its value within 1e-3 (a node whose value is 0
    within 1e-6 of the block's largest: its position goes through degrees and back)."""
    aoi, az, rad, data = _zemax_grid(DATA / name)
    table = import_file(DATA / name)[0].components[0]
    a, r = np.meshgrid(np.radians(az), np.radians(rad), indexing="ij")
    for j, ti in enumerate(aoi):
        t = math.radians(ti)
        s, e1, e2 = np.array([math.sin(t), 0, math.cos(t)]), np.array([-math.cos(t), 0, math.sin(t)]), np.array([0, -1.0, 0])
        wo = (np.cos(r)[..., None] * s + np.sin(r)[..., None] * (np.cos(a)[..., None] * e1 + np.sin(a)[..., None] * e2))
        keep = (wo[..., 2] > 1e-3) & ~np.isnan(data[0, j]) & ((r > 0) | (a == 0))  # R = 0: one direction
        want = data[0, j][keep]
        wi = np.tile([-math.sin(t), 0.0, math.cos(t)], (len(want), 1))
        got = table.brdf(wi, wo[keep])
        np.testing.assert_allclose(got, want, rtol=1e-3, atol=1e-6 * want.max(), err_msg=f"{name} incidence {ti}")


def test_an_imported_table_is_a_material_a_fresh_process_traces(tmp_path):
    """A scene names the imported material's file; a new process (which has not imported the file
    reader) loads its ``bsdf_table`` component and traces it (CONTRACTS 5.2: sampled like any other)."""
    import subprocess
    import sys

    out = tmp_path / "aeroglaze.json"
    assert _run("material", "import", DATA / "aeroglaze.bsdf", "-o", out) == 0
    scene = tmp_path / "scene.toml"
    scene.write_text(f"""[[part]]
name = "plate"
surface = {{type = "plane", vertex_mm = [0.0, 0.0, 0.0], axis = [0.0, 0.0, 1.0], outer_radius_mm = 30.0}}
material = "{out.as_posix()}"
[[part]]
name = "det"
surface = {{type = "plane", vertex_mm = [-15.0, 0.0, 15.0], axis = [1.0, 0.0, -1.0], outer_radius_mm = 5.0}}
role = "detector"
[[source]]
type = "collimated_disk"
center_mm = [0.0, 0.0, 40.0]
normal = [0.0, 0.0, -1.0]
direction = [0.0, 0.0, -1.0]
radius_mm = 5.0
power_w = 1.0
""")
    code = "from materials.material import load_material; import sys; print(load_material(sys.argv[1]).components[0].type_name)"
    got = subprocess.run([sys.executable, "-c", code, str(out)], capture_output=True, text=True)
    assert got.returncode == 0 and got.stdout.strip() == "bsdf_table", got.stderr
    js = tmp_path / "trace.json"
    run = subprocess.run([sys.executable, "-m", "straylight.cli.main", "trace", str(scene), "--rays", "2000", "--json", str(js)],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert json.loads(js.read_text())["detectors"]["det"]["power_w"] > 0
