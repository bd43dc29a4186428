"""A window written as a lens file (CODE V and Zemax), imported and its ghost traced, bare and coated.

A plane-parallel plate at normal incidence: of the collimated beam through its clear aperture (radius r of
a source of radius r_src: a fraction (r / r_src)^2 of the 1 W), (1 - R)^2 reaches the detector on the design
path and (1 - R)^2 R^2 on the one ghost (incoherent plate, Born & Wolf 7.6.1), R = ((n - 1) / (n + 1))^2. With
``--coating mgf2_quarter_wave`` (one MgF2 layer, n 1.38, a quarter wave at the traced wavelength) R is the
thin-film value ((n - 1.38^2) / (n + 1.38^2))^2 (Macleod, Thin-Film Optical Filters 3.2). The window is afocal:
the detector catches the whole beam (before, it was sized for an image: 1.2 mm, 1 % of the beam).
"""
import json
import tomllib

import pytest

SEQ = """RDM
TIT 'window'
EPD 20
DIM M
WL 550
YAN 0
SO 0 1e20
S 0 5 N-BK7
S 0 10
SI 0 0
GO
"""

ZMX = """VERS 190513 80 123457
MODE SEQ
NAME window
UNIT MM X W X CM MR CPMM
ENPD 20
FTYP 0 0 1 1 0 0 0
XFLN 0
YFLN 0
WAVM 1 0.55 1
SURF 0
  TYPE STANDARD
  CURV 0.0
  DISZ INFINITY
SURF 1
  STOP
  TYPE STANDARD
  CURV 0.0
  DISZ 5
  GLAS N-BK7 1 0 1.5168 64.17
  DIAM 12 1 0 0 1 ""
SURF 2
  TYPE STANDARD
  CURV 0.0
  DISZ 10
  DIAM 12 1 0 0 1 ""
SURF 3
  TYPE STANDARD
  CURV 0.0
  DISZ 0
"""


def _import(tmp_path, name, text, *extra):
    from straylight.cli.main import main

    lens = tmp_path / name
    lens.write_text(text)
    out = tmp_path / ("coated" if extra else "bare")
    assert main(["optics", "import", str(lens), "--out", str(out), *extra]) == 0
    return out


@pytest.mark.parametrize("name, text", [("window.seq", SEQ), ("window.zmx", ZMX)], ids=["seq", "zmx"])
def test_a_window_lens_file_has_the_plate_ghost_bare_and_coated(name, text, tmp_path):
    from straylight.analyses.ghost_trace import ghosts

    bare_dir = _import(tmp_path, name, text)
    coated_dir = _import(tmp_path, name, text, "--coating", "mgf2_quarter_wave")
    doc = json.loads((bare_dir / "prescription.json").read_text())
    n = doc["surfaces"][0]["n"]
    assert doc["efl_mm"] is None  # afocal
    scene = tomllib.loads((bare_dir / "scene.toml").read_text())
    parts = {p["name"]: p for p in scene["part"]}
    r_win = parts["s1"]["surface"]["outer_radius_mm"]
    r_src = scene["source"][0]["radius_mm"]
    assert parts["image"]["surface"]["outer_radius_mm"] > r_src  # the whole beam on the detector
    through = (r_win / r_src) ** 2

    bare = ghosts(bare_dir / "scene.toml", order=2, seed=1)
    coated = ghosts(coated_dir / "scene.toml", order=2, seed=1)
    R_b = ((n - 1) / (n + 1)) ** 2
    R_c = ((n - 1.38 ** 2) / (n + 1.38 ** 2)) ** 2
    for table, R in ((bare, R_b), (coated, R_c)):
        assert len(table.rows) == 1 and table.rows[0].surfaces == ["s2", "s1"]
        nominal, ghost = table.nominal, table.rows[0]
        # the rim: rays between s1's aperture and s2's (1e-3 mm wider) meet the lens edge; 4 sigma
        assert abs(nominal.power_w - through * (1 - R) ** 2) < 4 * nominal.stderr_w + 2e-3, (nominal.power_w, R)
        assert abs(ghost.power_w - through * (1 - R) ** 2 * R ** 2) < 4 * ghost.stderr_w + 2e-3 * ghost.power_w
    ratio = coated.rows[0].power_w / bare.rows[0].power_w
    expected = (R_c / R_b) ** 2 * ((1 - R_c) / (1 - R_b)) ** 2
    rel = ((coated.rows[0].stderr_w / coated.rows[0].power_w) ** 2
           + (bare.rows[0].stderr_w / bare.rows[0].power_w) ** 2) ** 0.5
    assert abs(ratio / expected - 1) < 4 * rel, (ratio, expected)
