"""Hostile input: a measured scan that gives one point (wavelength, polarization, angles) two different
BRDF values was accepted (main 13a6b5b) and both rows were fitted as truth. Now refused in one line
naming both lines; an exact repeat still reads."""
from __future__ import annotations

import pytest

from materials.scan import CSV_COLUMNS, ScanError, read_scan
from straylight.cli.main import main

HEADER = ",".join(CSV_COLUMNS) + "\n"


def _row(brdf, tr=10.0, phi=0.0, pol="s"):
    values = {"wavelength_nm": 532.0, "polarization": pol, "theta_i_deg": 30.0, "theta_r_deg": tr, "phi_r_deg": phi,
              "brdf_per_sr": brdf, "brdf_std_per_sr": 0.0, "n_repeats": 3}
    return ",".join(str(values[c]) for c in CSV_COLUMNS) + "\n"


def test_conflicting_repeat_refused(tmp_path, capsys):
    path = tmp_path / "scan.csv"
    path.write_text(HEADER + _row(0.5) + _row(0.2, tr=20.0) + _row(0.7))
    with pytest.raises(ScanError, match=r"line 4, column brdf_per_sr: repeats the point of line 2 .* \(0.7 vs 0.5\)"):
        read_scan(path)
    assert main(["material", "fit", str(path), "-o", str(tmp_path / "m.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "repeats the point of line 2" in err


def test_phi_360_is_the_same_point(tmp_path):
    path = tmp_path / "scan.csv"
    path.write_text(HEADER + _row(0.5, phi=0.0) + _row(0.6, phi=360.0))
    with pytest.raises(ScanError, match="repeats the point"):
        read_scan(path)


def test_exact_repeat_and_other_polarization_read(tmp_path):
    path = tmp_path / "scan.csv"
    path.write_text(HEADER + _row(0.5) + _row(0.5) + _row(0.9, pol="p"))
    assert len(read_scan(path)) == 3
