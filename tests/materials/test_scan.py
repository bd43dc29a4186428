"""Scan CSV (CONTRACTS §2): round trip, incremental writes, and one precise error per malformed case."""
import numpy as np
import pytest

from materials.scan import (
    CSV_COLUMNS, ScanError, append_rows, header_text, make_scan, read_scan, write_scan,
)

HEADER = ",".join(CSV_COLUMNS)
GOOD_ROW = "532,s,30,30.5,0,0.12,0.004,3"


def _scan():
    return make_scan(
        wavelength_nm=532.0,
        polarization=np.array(["s", "s", "p", "p"]),
        theta_i_deg=[10.0, 10.0, 70.0, 70.0],
        theta_r_deg=[10.05, -40.0, 75.0, 20.0],
        phi_r_deg=[0.0, 0.0, 0.0, 180.0],
        brdf_per_sr=[0.1234567890123, np.nan, -1e-6, 0.0086],
        brdf_std_per_sr=[0.004, 0.0, np.nan, 1e-4],
        n_repeats=[3, 3, 1, 3],
        metadata={"sample": "Z302 #2", "rig.arm_mm": "200"},
    )


def test_round_trip_is_exact(tmp_path):
    scan = _scan()
    path = write_scan(tmp_path / "s.csv", scan)
    back = read_scan(path)
    assert back.metadata == {"sample": "Z302 #2", "rig.arm_mm": "200"}
    assert back.path == path
    for name in CSV_COLUMNS:
        a, b = getattr(scan, name), getattr(back, name)
        if a.dtype.kind == "f":
            np.testing.assert_array_equal(a, b)  # NaN == NaN for this assert
        else:
            assert a.tolist() == b.tolist()
    text = path.read_text().splitlines()
    assert text[0] == "# sample: Z302 #2" and text[2] == HEADER
    assert not list(tmp_path.glob(".*tmp")), "temp file left behind"


def test_flags_and_angle_helpers():
    scan = _scan()
    assert scan.flagged.tolist() == [False, True, True, False]
    # negative theta_r is the mirror direction: backscatter half-plane
    np.testing.assert_allclose(np.degrees(scan.theta_r), [10.05, 40.0, 75.0, 20.0])
    np.testing.assert_allclose(np.degrees(scan.phi_r), [0.0, 180.0, 0.0, 180.0])
    np.testing.assert_allclose(scan.signed_theta_r_deg, [10.05, -40.0, 75.0, -20.0])
    assert scan.incidence_angles_deg.tolist() == [10.0, 70.0]
    assert scan.polarizations == ("s", "p")
    assert len(scan.by_polarization("p")) == 2
    keys = [k for k, _ in scan.groups()]
    assert keys == [(10.0, "s"), (70.0, "p")]
    assert scan.metadata_float("rig.arm_mm") == 200.0
    assert scan.metadata_float("rig.slit_width_mm", 0.2) == 0.2


def test_append_rows_builds_a_readable_file(tmp_path):
    path = tmp_path / "live.csv"
    append_rows(path, metadata={"sample": "x"}, wavelength_nm=532, polarization="s", theta_i_deg=10,
                theta_r_deg=[9.5, 10.0], phi_r_deg=0, brdf_per_sr=[1.0, 2.0], brdf_std_per_sr=0.1, n_repeats=3)
    append_rows(path, wavelength_nm=532, polarization="p", theta_i_deg=10,
                theta_r_deg=10.5, phi_r_deg=0, brdf_per_sr=0.5, brdf_std_per_sr=0.1, n_repeats=3)
    scan = read_scan(path)
    assert len(scan) == 3 and scan.metadata == {"sample": "x"}
    assert scan.polarization.tolist() == ["s", "s", "p"]
    assert path.read_text().count(HEADER) == 1


def test_reader_accepts_missing_metadata_and_other_column_order(tmp_path):
    cols = list(CSV_COLUMNS)[::-1] + ["extra"]
    row = dict(zip(CSV_COLUMNS, GOOD_ROW.split(",")))
    path = tmp_path / "r.csv"
    path.write_text(",".join(cols) + "\n" + ",".join(row.get(c, "x") for c in cols) + "\n")
    scan = read_scan(path)
    assert scan.metadata == {} and scan.theta_r_deg[0] == 30.5 and scan.n_repeats[0] == 3


@pytest.mark.parametrize(
    "header, row, line, column",
    [
        (HEADER.replace(",n_repeats", ""), GOOD_ROW.rsplit(",", 1)[0], 2, "n_repeats"),  # header line
        (HEADER, GOOD_ROW.replace("0.12", "abc"), 4, "6 (brdf_per_sr)"),
        (HEADER, GOOD_ROW.replace("0.004", "-0.004"), 4, "7 (brdf_std_per_sr)"),
        (HEADER, GOOD_ROW.replace(",30,30.5,", ",30,95,"), 4, "4 (theta_r_deg)"),
        (HEADER, GOOD_ROW.replace(",30,30.5,", ",-91,30.5,"), 4, "3 (theta_i_deg)"),
        (HEADER, GOOD_ROW.replace(",s,", ",x,"), 4, "2 (polarization)"),
        (HEADER, GOOD_ROW.replace("0.004", "inf"), 4, "7 (brdf_std_per_sr)"),
    ],
    ids=["missing-column", "non-numeric", "negative-std", "theta-r-range", "theta-i-range", "polarization",
         "infinite-std"],
)
def test_malformed_csv_error_names_file_line_column(tmp_path, header, row, line, column):
    path = tmp_path / "bad.csv"
    # line 1 metadata, line 2 header, line 3 a good row, line 4 the bad row
    body = f"# sample: s\n{header}\n" + (GOOD_ROW + "\n" if "n_repeats" in header else "")
    path.write_text(body + row + "\n")
    with pytest.raises(ScanError) as info:
        read_scan(path)
    msg = str(info.value)
    assert "\n" not in msg
    assert str(path) in msg and f"line {line}" in msg and f"column {column}" in msg
    assert isinstance(info.value, ValueError)
    assert info.value.line == line


def test_a_file_with_no_data_rows_is_refused_naming_it_unless_resuming(tmp_path):
    path = tmp_path / "empty.csv"
    path.write_text(header_text({"sample": "s"}))
    with pytest.raises(ScanError, match="no data rows") as info:
        read_scan(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)
    assert len(read_scan(path, allow_empty=True).brdf_per_sr) == 0  # a scan stopped after its header resumes


def test_nan_and_negative_brdf_are_kept_not_rejected(tmp_path):
    path = tmp_path / "n.csv"
    path.write_text(header_text({}) + GOOD_ROW + "\n" + GOOD_ROW.replace("0.12", "nan") + "\n"
                    + GOOD_ROW.replace("0.12", "-3e-7") + "\n")
    scan = read_scan(path)
    assert len(scan) == 3 and scan.flagged.tolist() == [False, True, True]


def test_write_scan_validates_rows():
    with pytest.raises(ScanError, match="polarization"):
        make_scan(wavelength_nm=532, polarization="q", theta_i_deg=10, theta_r_deg=10, brdf_per_sr=1.0)
