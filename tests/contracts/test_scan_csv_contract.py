"""CONTRACTS §2 scan CSVs written by hand (not by the project's writer): metadata, missing metadata,
negative theta_r, NaN / negative brdf rows, and every malformed case -> one-line error naming file,
line and column, through ``straylight material fit`` and ``straylight rig diagnose``.
"""
import json
import math

import numpy as np
import pytest

from contract_helpers import assert_one_line_error

HEADER = "wavelength_nm,polarization,theta_i_deg,theta_r_deg,phi_r_deg,brdf_per_sr,brdf_std_per_sr,n_repeats"
RD = 0.043  # generating Lambertian: BRDF = rd / pi (CONTRACTS §5)


def _rows(rd=RD, pols="sp", tis=(12.0, 47.0), trs=(-60.0, -20.0, 0.0, 15.0, 40.0, 75.0)):
    rows = []
    for pol in pols:
        for ti in tis:
            for tr in trs:
                rows.append(f"1064.0,{pol},{ti},{tr},0.0,{rd / math.pi!r},{0.02 * rd / math.pi!r},4")
    return rows


def _write(path, lines, metadata=True):
    meta = ["# sample: hand-made grey", "# rig.arm_mm: 410.0", "# rig.slit_width_mm: 3.0",
            "# date: 2026-01-02T03:04:05Z"] if metadata else []
    path.write_text("\n".join(meta + lines) + "\n", encoding="utf-8")
    return path, len(meta)


def test_reader_metadata_and_missing_metadata(tmp_path):
    from materials.scan import read_scan

    p, _ = _write(tmp_path / "with.csv", [HEADER] + _rows())
    scan = read_scan(p)
    assert scan.metadata["sample"] == "hand-made grey"
    assert float(scan.metadata["rig.arm_mm"]) == 410.0
    assert len(scan) == 24
    q, _ = _write(tmp_path / "without.csv", [HEADER] + _rows(), metadata=False)
    bare = read_scan(q)
    assert bare.metadata == {} and len(bare) == 24
    np.testing.assert_array_equal(bare.theta_r_deg, scan.theta_r_deg)
    assert (scan.theta_r_deg < 0).sum() == 8  # negative theta_r rows are kept


def test_nan_and_negative_brdf_kept_flagged_and_fit_survives(cli, tmp_path):
    from materials.scan import read_scan

    rows = _rows()
    rows[1] = rows[1].replace(f",{RD / math.pi!r},", ",nan,")
    rows[7] = rows[7].replace(f",{RD / math.pi!r},", ",-3.5e-05,")
    rows[9] = rows[9].replace(f",{RD / math.pi!r},", ",inf,")  # an overloaded lock-in
    rows[11] = rows[11].replace(f",{0.02 * RD / math.pi!r},", ",nan,")  # unknown std
    p, _ = _write(tmp_path / "noisy.csv", [HEADER] + rows)
    scan = read_scan(p)
    assert len(scan) == 24 and int(scan.flagged.sum()) == 3
    out = tmp_path / "fit.json"
    rc, _, err = cli("material", "fit", p, "--model", "lambertian", "-o", out, "--starts", 2)
    assert rc == 0, err
    rd = json.loads(out.read_text())["components"][0]["rd"]
    assert rd == pytest.approx(RD, rel=1e-3)  # exact data, the generating rd comes back


BAD = [
    # (description, edit(lines) -> lines, expected line (after metadata), column text)
    ("missing column", lambda L: [L[0].replace(",n_repeats", "")] + [r.rsplit(",", 1)[0] for r in L[1:]], 1,
     "n_repeats"),
    ("non-numeric theta_i", lambda L: L[:3] + [L[3].replace(",12.0,", ",twelve,", 1)] + L[4:], 4, "theta_i_deg"),
    ("non-numeric brdf", lambda L: L[:5] + [L[5].replace(f",{RD / math.pi!r},", ",1.2.3,")] + L[6:], 6,
     "brdf_per_sr"),
    ("negative std", lambda L: L[:2] + [L[2].replace(f",{0.02 * RD / math.pi!r},", ",-1e-4,")] + L[3:], 3,
     "brdf_std_per_sr"),
    ("theta_i > 90", lambda L: L[:9] + [L[9].replace(",47.0,", ",91.0,", 1)] + L[10:], 10, "theta_i_deg"),
    ("theta_r < -90", lambda L: L[:1] + [L[1].replace(",-60.0,", ",-90.5,", 1)] + L[2:], 2, "theta_r_deg"),
    ("unknown polarization", lambda L: L[:4] + [L[4].replace(",s,", ",x,", 1)] + L[5:], 5, "polarization"),
    ("a row with a value past the header", lambda L: L[:7] + [L[7] + ",3"] + L[8:], 8, "9 (no column)"),
]


@pytest.mark.parametrize("desc,edit,line,column", BAD, ids=[b[0] for b in BAD])
@pytest.mark.parametrize("metadata", [True, False])
def test_malformed_scan_fit(cli, tmp_path, desc, edit, line, column, metadata):
    p, n_meta = _write(tmp_path / "bad_scan.csv", edit([HEADER] + _rows()), metadata=metadata)
    rc, _, err = cli("material", "fit", p, "--model", "lambertian", "-o", tmp_path / "m.json")
    msg = assert_one_line_error(rc, err, "bad_scan.csv", f"line {line + n_meta}", column)
    assert "column" in msg
    assert not (tmp_path / "m.json").exists()


@pytest.mark.parametrize("desc,edit,line,column", BAD[::2], ids=[b[0] for b in BAD[::2]])
def test_malformed_scan_diagnose(cli, tmp_path, desc, edit, line, column):
    p, n_meta = _write(tmp_path / "bad_scan.csv", edit([HEADER] + _rows()))
    rc, _, err = cli("rig", "diagnose", p, "--json", tmp_path / "d.json")
    assert_one_line_error(rc, err, "bad_scan.csv", f"line {line + n_meta}", column)
    assert not (tmp_path / "d.json").exists()


def test_missing_scan_file(cli, tmp_path):
    rc, _, err = cli("material", "fit", tmp_path / "nowhere.csv", "-o", tmp_path / "m.json")
    assert_one_line_error(rc, err, "nowhere.csv")


def test_negative_theta_r_is_the_backscatter_half_plane(cli, tmp_path):
    """(theta_r = -t, phi_r = 0) and (theta_r = t, phi_r = 180) are the same direction: same fit."""
    from materials import load_material
    from materials.base import brdf_angles

    mat = load_material({"name": "lobe", "wavelength_nm": 633.0, "components": [
        {"type": "lambertian", "rd": 0.03}, {"type": "abg", "a": 2e-3, "b": 2e-3, "g": 1.8}]})
    rows_neg, rows_phi = [], []
    for ti in (15.0, 40.0):
        for t in (5.0, 20.0, 35.0, 50.0, 70.0):
            for sign in (1, -1):
                f = float(np.ravel(brdf_angles(mat, np.radians(ti), np.radians(t), 0.0 if sign > 0 else np.pi, "s"))[0])
                rows_neg.append(f"633.0,s,{ti},{sign * t},0.0,{f!r},{0.01 * f!r},3")
                rows_phi.append(f"633.0,s,{ti},{t},{0.0 if sign > 0 else 180.0},{f!r},{0.01 * f!r},3")
    fits = []
    for name, rows in (("neg.csv", rows_neg), ("phi.csv", rows_phi)):
        p, _ = _write(tmp_path / name, [HEADER] + rows)
        out = tmp_path / f"{name}.json"
        rc, _, err = cli("material", "fit", p, "--model", "lambertian+abg", "-o", out, "--starts", 2)
        assert rc == 0, err
        fits.append(json.loads(out.read_text())["components"])
    assert fits[0] == fits[1]
    assert fits[0][0]["rd"] == pytest.approx(0.03, rel=0.02)  # the generating Lambertian comes back
