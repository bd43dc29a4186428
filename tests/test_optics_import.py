"""optics import / optics info (docs/optics.md): every corpus lens file imports or is refused in one line;
first-order data checked against an independent paraxial y-nu trace of the written surface table."""
import json
import math
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
LENSES = ROOT / "tests" / "data" / "lenses"
CORPUS = sorted(p for p in LENSES.rglob("*") if p.suffix.lower() in (".seq", ".zmx"))

# files refused, and the words their one-line refusal must carry
REFUSED = {
    "curved_reflective_grating.zmx": "diffractive",
    "ASL5040-UV.zmx": "surface type QED_TYPE",   # a Forbes Q asphere: rayoptics keeps only its base conic
    "CODV_65988.seq": "diffractive",
    "US05831776-1.zmx": "finite distance",       # its SILICA is fused silica (other_materials)
    "singlet.seq": "finite distance",
    "tilt_test.seq": "no optical surface",
    "dec_rev_tilt_test.seq": "no optical surface",
    "Canon_EF24mm_f1.4L_II_USM.zmx": "could not parse",  # a '??' in a number of the file
    "Plossl_USP4482217.zmx": "finite distance",          # an eyepiece traced from its eye side
    "Microscope_USP3893752.zmx": "finite distance",
    "Telecentric_USP4929066.zmx": "finite distance",
    "CODV_35571.seq": "could not parse",                 # rayoptics' CODE V reader: an HMY aperture it cannot read
    # its XASPHERE terms as Zemax defines them (even powers) give 1e22 mm of sag at the rim: not a surface
    "Sigma_14-24mm_F2.8_DG_DN_A.zmx": "surface 5: the asphere's terms give a sag of -2.12e+22 mm",
    # its mirrors read, the file ends on a lone surface with the image on it: the patent's rear groups are missing
    "Vivitar_Series_1_450mm_F4.5_Solid_Mirror.zmx": "the image surface is on surface 9",
}


class _Result:
    def __init__(self, returncode, stdout, stderr):
        self.returncode, self.stdout, self.stderr = returncode, stdout, stderr


def _run(*args, cwd=None):
    """The straylight command in this process (stdout, stderr captured)."""
    import contextlib
    import io
    import os

    from straylight.cli.main import main

    out, err = io.StringIO(), io.StringIO()
    old = os.getcwd()
    try:
        if cwd:
            os.chdir(cwd)
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            rc = main([str(a) for a in args])
    finally:
        os.chdir(old)
    return _Result(rc, out.getvalue(), err.getvalue())


def test_corpus_is_large_enough():
    assert len(CORPUS) >= 20
    assert len({p.parent.name for p in CORPUS}) >= 3
    assert (LENSES / "LICENSES.md").exists()


@pytest.mark.parametrize("lens", CORPUS, ids=lambda p: p.name)
def test_every_file_imports_or_is_refused_in_one_line(lens, tmp_path):
    r = _run("optics", "import", lens, "--out", tmp_path / "out")
    if lens.name in REFUSED:
        assert r.returncode == 2, r.stderr
        lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
        assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
        assert REFUSED[lens.name] in lines[0], lines[0]
    else:
        assert r.returncode == 0, r.stderr
        doc = json.loads((tmp_path / "out" / "prescription.json").read_text())
        assert {"file", "units_in_file", "wavelength_nm", "efl_mm", "bfl_mm", "fno", "epd_mm", "fields_deg",
                "surfaces"} <= set(doc)
        for s in doc["surfaces"]:
            assert {"name", "type", "radius_mm", "conic", "coefficients", "thickness_mm", "glass", "n",
                    "semi_diameter_mm", "mirror"} <= set(s)
        assert "Traceback" not in r.stderr
        # numpy's floating-point warnings (a rayoptics ray that misses a surface comes back NaN) say nothing
        # to the user about the lens: every warning line is the import's own
        assert "encountered in" not in r.stderr, r.stderr
        assert "nan" not in r.stdout.lower(), r.stdout  # an afocal system's summary says so, not "efl nan mm"


def _paraxial_efl(surfaces):
    """EFL from a y-nu paraxial trace of the surface table (coaxial, no mirrors): y' = y + t u, n'u' = nu - y phi."""
    y, nu, n = 1.0, 0.0, 1.0
    for i, s in enumerate(surfaces):
        c = 0.0 if s["radius_mm"] is None else 1.0 / s["radius_mm"]
        n2 = s["n"]
        nu = nu - y * (n2 - n) * c
        n = n2
        if i < len(surfaces) - 1:
            y = y + s["thickness_mm"] * nu / n
    return -1.0 / nu


@pytest.mark.parametrize("name", ["ray-optics/ag_dblgauss.seq", "optiland/lens1.zmx", "ray-optics/CODV_32327.seq",
                                  "OpticsDatabase/Edmund_32-299.zmx", "ray-optics/ACL3026U.zmx",
                                  "OpticsDatabase/Fujifilm_Fujinon_XF27mm_F2.8.zmx",  # odd terms: no paraxial power
                                  "OpticsDatabase/Canon_EF50mm_f1.0L_USM.zmx"])  # r^2 terms: paraboloids
def test_efl_matches_an_independent_paraxial_trace(name, tmp_path):
    r = _run("optics", "import", LENSES / name, "--out", tmp_path)
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / "prescription.json").read_text())
    assert not any(s["mirror"] for s in doc["surfaces"])
    assert math.isclose(_paraxial_efl(doc["surfaces"]), doc["efl_mm"], rel_tol=1e-4)


def test_info_prints_first_order_data_and_writes_nothing(tmp_path):
    lens = tmp_path / "dg.seq"
    lens.write_bytes((LENSES / "ray-optics" / "ag_dblgauss.seq").read_bytes())
    r = _run("optics", "info", lens, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "efl         100.0" in r.stdout and "mm" in r.stdout and "N-SSK2" in r.stdout and "stop" in r.stdout
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dg.seq"]


@pytest.mark.parametrize("name", ["tilt_test.seq", "dec_rev_tilt_test.seq"])
def test_info_refuses_what_import_refuses_in_the_same_line(name, tmp_path):
    """rayoptics' tilt test files (dummy surfaces with air on both sides, tilted and decentred): ``optics import``
    refuses them in one line, and ``info`` (which prints the surface table of an importable file) must too,
    with the same line and exit 2 (before: ``info`` printed a table of dummies and exited 0)."""
    lens = LENSES / "ray-optics" / name
    lines = []
    for args in (("optics", "info", lens), ("optics", "import", lens, "--out", tmp_path / "out")):
        r = _run(*args, cwd=tmp_path)
        assert r.returncode == 2, (args, r.stdout, r.stderr)
        err = [ln for ln in r.stderr.splitlines() if ln.strip()]
        assert len(err) == 1 and f"{name}: no optical surface" in err[0], r.stderr
        lines.append(err[0])
    assert lines[0] == lines[1]


def test_glass_option_supplies_a_missing_glass(tmp_path):
    r = _run("optics", "import", LENSES / "ray-optics" / "ACL3026U.zmx", "--glass", "B270=1.5230", "--out", tmp_path)
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / "prescription.json").read_text())
    assert any(s["glass"] == "B270" and s["n"] == 1.523 for s in doc["surfaces"])
    lens = tmp_path / "lens.seq"
    lens.write_text((LENSES / "optiland" / "fno_fields.seq").read_text().replace("1.5168:64.17", "MYGLASS"))
    r = _run("optics", "import", lens, "--out", tmp_path / "mine")
    assert r.returncode == 2 and "unknown glass MYGLASS" in r.stderr and "--glass MYGLASS=N" in r.stderr


def test_a_model_glass_given_by_its_numbers(tmp_path):
    """optiland's fno_fields.seq names its glass ``1.5168:64.17`` (nd:vd, no RDM): an equiconvex R 100 mm, 10 mm
    thick lens; its EFL is the thick-lens formula's (1/f = (n-1)(2/R - (n-1) t/(n R^2))) with n of the model
    glass at the traced wavelength (and the six-digit code 517642 is the same kind of glass)."""
    r = _run("optics", "import", LENSES / "optiland" / "fno_fields.seq", "--wavelength-nm", "587.56", "--out", tmp_path)
    assert r.returncode == 0, r.stderr
    assert "model glass nd 1.5168, vd 64.17" in r.stderr
    doc = json.loads((tmp_path / "prescription.json").read_text())
    n = doc["surfaces"][0]["n"]
    assert abs(n - 1.5168) < 1e-4  # at the d line the model glass is its nd
    R, t = 100.0, 10.0
    efl = 1.0 / ((n - 1) * (2 / R - (n - 1) * t / (n * R * R)))
    assert math.isclose(doc["efl_mm"], efl, rel_tol=1e-6)
    from straylight.optics.reader import _model_glass

    code = _model_glass("517642")
    assert code is not None and (code.n, code.v) == (1.517, 64.2)
    assert _model_glass("N-BK7") is None and _model_glass("999:0.1") is None


def test_crystals_and_fused_silica_lens_files_name(tmp_path):
    """Fused silica (SILICA, F_SILICA, C79-80...), CaF2 and sapphire from Malitson's Sellmeier fits, checked
    against the d-line indices those papers tabulate (fused silica 1.45846, J. Opt. Soc. Am. 55, 1205; CaF2
    1.43385, Appl. Opt. 2, 1103; sapphire n_o 1.7682, J. Opt. Soc. Am. 52, 1377); B270 as a model glass
    from Schott's nd 1.5230."""
    from straylight.optics import other_materials as om

    # LITHOTEC-CAF2: Schott's CaF2, gone from its catalogue (a 60x microscope objective of tangericm/optical-design)
    for name, nd in (("SILICA", 1.45846), ("C79-80", 1.45846), ("CAF2", 1.43385), ("LITHOTEC-CAF2", 1.43385),
                     ("SAPPHIRE", 1.7682)):
        medium = om.medium(name)
        assert abs(medium.rindex(587.56) - nd) < 5e-5, name  # the papers tabulate 4-5 decimals
    assert abs(om.medium("B270").rindex(587.56) - 1.5230) < 1e-4
    assert om.medium("N-BK7") is None
    r = _run("optics", "import", LENSES / "ray-optics" / "ACL3026U.zmx", "--out", tmp_path)
    assert r.returncode == 0 and "glass B270 read as" in r.stderr, r.stderr


def test_imported_scene_loads_and_traces(tmp_path):
    from straylight.scene import load_scene

    r = _run("optics", "import", LENSES / "ray-optics" / "ag_dblgauss.seq", "--out", tmp_path)
    assert r.returncode == 0, r.stderr
    scene = load_scene(tmp_path / "scene.toml")
    names = {p.name for p in scene.scene.parts}
    assert {"image", "stop", "s1", "s11"} <= names
    assert any(n.startswith("edge_") for n in names)
    t = _run("trace", tmp_path / "scene.toml", "--rays", 2000, "--json", tmp_path / "t.json")
    assert t.returncode == 0, t.stderr
    out = json.loads((tmp_path / "t.json").read_text())
    assert out["detectors"]["image"]["power_w"] > 0.2


def test_two_glasses_of_one_label_keep_their_own_indices():
    """The Fujinon-SW 65 mm's 1.69359 / 53.4 and 1.69350 / 53.4 both round to the label 694.534: each interface
    still traces with its own surface's index as the file gives it (the second element took the first's)."""
    from straylight.optics.reader import read_prescription
    from straylight.optics.scene_build import build_scene

    p = read_prescription(LENSES / "OpticsDatabase" / "Fujifilm_Fujinon-SW_65mm_F5.6.zmx")
    scene = build_scene(p)
    parts = {part["name"]: part for part in scene["part"]}
    second = [surf.name for surf in p.surfaces if 1.6935 in (round(surf.n, 5), round(surf.n_before, 5))]
    assert second, "the file's second glass"
    for name in second:  # into it from the glass in contact (one interface), and out of it into air
        comp = scene["material"][parts[name]["material"]]["components"][0]
        assert comp["n"] == pytest.approx(1.6935, abs=1e-7), name
    glasses = {round(comp["n"], 5) for m in scene["material"].values() for comp in m["components"]
               if comp["type"] == "dielectric"}
    assert {1.69359, 1.6935} <= glasses


def test_real_image_height_fields_are_the_angles_whose_rays_land_there():
    """Zemax fields given as real image heights (FTYP 3, most of OpticsDatabase): the Wray 64 mm f/0.7's edge field
    is 13.5 mm on the image. atan(13.5 / efl) = 11.89 deg was read, where no ray passes the lens (its distortion);
    the field is the angle of the chief ray rayoptics aims at 13.5 mm, 8.69 deg: the sequential trace passes rays
    there, their spot lies near that height (at f/0.74 the vignetted beam's centroid sits 1.8 mm inside the chief
    ray), and the detector is 1.2 x the file's 13.5 mm."""
    from straylight.optics.reader import read_prescription
    from straylight.optics.scene_build import build_scene
    from straylight.optics.sequential import sequential_spot

    p = read_prescription(LENSES / "OpticsDatabase" / "Wray_64mm_F0.7.zmx")
    edge = max(p.fields_deg)
    assert edge < 10.0 and math.degrees(math.atan2(13.5, abs(p.efl_mm))) > 11.0
    scene = build_scene(p, field_deg=edge)
    src = scene["source"][0]
    spot = sequential_spot(p, edge, src["center_mm"][2], src["radius_mm"], n=3000,
                           source_centre_xy=src["center_mm"][:2], min_kept=300)
    assert len(spot) > 50
    assert 0.8 * 13.5 < np.hypot(*spot.mean(axis=0)[:2]) < 1.05 * 13.5
    det = next(part for part in scene["part"] if part["name"] == "image")
    assert det["surface"]["outer_radius_mm"] == pytest.approx(1.2 * 13.5, rel=1e-6)


def test_readers_write_no_log_files_in_the_working_folder(tmp_path):
    for name in ("ray-optics/ag_dblgauss.seq", "optiland/lens1.zmx"):
        r = _run("optics", "info", LENSES / name, cwd=tmp_path)
        assert r.returncode == 0, r.stderr
    assert list(tmp_path.iterdir()) == []


def test_coating_option_writes_the_coating_key_on_glass_air_surfaces(tmp_path):
    import tomllib

    r = _run("optics", "import", LENSES / "OpticsDatabase" / "Edmund_32-299.zmx", "--coating", "mgf2_quarter_wave",
             "--out", tmp_path)
    assert r.returncode == 0, r.stderr
    doc = tomllib.loads((tmp_path / "scene.toml").read_text())
    comps = [c for m in doc["material"].values() for c in m["components"] if c["type"] == "dielectric"]
    outer = [c for c in comps if "n_outside" not in c]   # glass against air: coated
    inner = [c for c in comps if "n_outside" in c]       # the cemented surface: not
    assert outer and all(c.get("coating") == "mgf2_quarter_wave" for c in outer)
    assert inner and all("coating" not in c for c in inner)


def test_a_vendor_mgf2_coating_is_one_quarter_wave_layer_at_its_own_wavelength(tmp_path):
    """Edmund writes EO_MGF2(550nm): one MgF2 layer (n = 1.38) a quarter wave thick at 550 nm, 550 / (4 x 1.38) =
    99.64 nm, whatever wavelength is traced."""
    r = _run("optics", "import", LENSES / "OpticsDatabase" / "Edmund_32-299.zmx", "--out", tmp_path)
    assert r.returncode == 0
    assert "coating EO_MGF2(550nm) of the file read as one quarter-wave MgF2 layer at 550 nm" in r.stderr
    import tomllib

    scene = tomllib.loads((tmp_path / "scene.toml").read_text())
    coated = [c for m in scene["material"].values() for c in m["components"] if c.get("coating")]
    assert coated and all(c["coating"] == [{"n": 1.38, "thickness_nm": pytest.approx(99.6377, abs=1e-3)}] for c in coated)


def test_a_coating_named_in_the_file_but_unknown_is_warned_not_dropped_silently(tmp_path):
    text = (LENSES / "OpticsDatabase" / "Edmund_32-299.zmx").read_bytes()
    text = text.decode("utf-16") if text[:2] in (b"\xff\xfe", b"\xfe\xff") else text.decode("utf-8")
    lens = tmp_path / "v.zmx"
    lens.write_text(text.replace("EO_MGF2(550nm)", "VENDOR_V2"), encoding="utf-8")
    r = _run("optics", "import", lens, "--out", tmp_path / "out")
    assert r.returncode == 0
    assert "coating 'VENDOR_V2'" in r.stderr
    doc = json.loads((tmp_path / "out" / "prescription.json").read_text())
    assert any("VENDOR_V2" in w for w in doc["warnings"])


def test_a_zemax_ar_coating_is_read_as_the_quarter_wave_mgf2_design(tmp_path):
    """OpticStudio's COATING.DAT defines AR (and MGF2) as one quarter-wave MgF2 layer: read as mgf2_quarter_wave."""
    src = (LENSES / "OpticsDatabase" / "Edmund_32-299.zmx").read_bytes()
    for enc in ("utf-16", "utf-8"):
        try:
            text = src.decode(enc)
            break
        except UnicodeDecodeError:
            continue
    assert "EO_MGF2(550nm)" in text
    lens = tmp_path / "ar.zmx"
    lens.write_text(text.replace("EO_MGF2(550nm)", "AR"), encoding="utf-8")
    r = _run("optics", "import", lens, "--out", tmp_path / "out")
    assert r.returncode == 0, r.stderr
    assert "read as mgf2_quarter_wave" in r.stderr
    import tomllib

    scene = tomllib.loads((tmp_path / "out" / "scene.toml").read_text())
    coated = [c for m in scene["material"].values() for c in m["components"] if c.get("coating")]
    assert coated and all(c["coating"] == "mgf2_quarter_wave" for c in coated)


def test_a_substituted_glass_is_named(tmp_path):
    """rayoptics replaces a glass it cannot find as written by a similar catalogue glass; the warning names both
    (354710-C.zmx: D-ZK3M, a moulding glass of CDGM's, read as D-ZK3)."""
    r = _run("optics", "info", LENSES / "ray-optics" / "354710-C.zmx")
    assert r.returncode == 0, r.stderr
    assert "glass D-ZK3M is not in the catalogues as written; rayoptics substituted D-ZK3 (CDGM)" in r.stdout + r.stderr


def test_a_truncated_lens_file_is_refused_in_one_line_naming_it(tmp_path):
    """A CODE V file cut off after its first surface (no image surface: rayoptics finds no ray through it)
    is one error line naming the file, not rayoptics' internal TypeError."""
    cut = tmp_path / "cut.seq"
    cut.write_bytes((LENSES / "ray-optics" / "CODV_32327.seq").read_bytes()[:300])
    r = _run("optics", "import", cut, "--out", tmp_path / "out")
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert str(cut) in lines[0] and "no ray passes the system" in lines[0], lines[0]


def _cut_nikkor_20mm(how: str) -> bytes:
    """Nikon_Nikkor_20mm_f4.zmx (21 surfaces, ASCII, CRLF) cut inside its surface list as a download that stopped
    would leave it: after surface 8's DISZ line (``line``), inside its DIAM line (``mid-line``), or after its whole
    block (``block``: surface 8, a glass's front, read as the image)."""
    raw = (LENSES / "OpticsDatabase" / "Nikon_Nikkor_20mm_f4.zmx").read_bytes()
    lines = raw.decode("latin-1").splitlines(keepends=True)
    surf = [k for k, ln in enumerate(lines) if ln.startswith("SURF")]
    assert len(surf) == 21
    block = lines[surf[8]:surf[9]]
    disz = surf[8] + next(k for k, ln in enumerate(block) if ln.split()[:1] == ["DISZ"])
    diam = surf[8] + next(k for k, ln in enumerate(block) if ln.split()[:1] == ["DIAM"])
    cut = {"line": "".join(lines[:disz + 1]), "mid-line": "".join(lines[:diam]) + lines[diam][:9],
           "block": "".join(lines[:surf[9]])}[how]
    return cut.encode("latin-1")


@pytest.mark.parametrize("how, words", [
    ("line", "line 126: the file ends inside surface 8, which has no DIAM line"),
    ("mid-line", "line 128: the file ends inside surface 8, which has no POPS line"),
    ("block", "line 127: the last surface (8) has glass ___BLANK after it, as a lens surface has: no image surface"),
])
def test_a_zemax_file_cut_inside_its_surface_list_is_refused_naming_the_line(how, words, tmp_path):
    """A Zemax file cut short inside its surfaces (a download that stopped) was read as a shorter lens, without a
    word (the cut Nikkor: 7 optical surfaces, EFL -32 mm): now one line naming the file, the line and the surface."""
    cut = tmp_path / "cut.zmx"
    cut.write_bytes(_cut_nikkor_20mm(how))
    r = _run("optics", "import", cut, "--out", tmp_path / "out")
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert str(cut) in lines[0] and words in lines[0], lines[0]
    assert not (tmp_path / "out" / "scene.toml").exists()


def test_a_utf16_zemax_file_cut_inside_a_character_is_refused(tmp_path):
    raw = (LENSES / "OpticsDatabase" / "Triplet_GB22607_Taylor1893.zmx").read_bytes()
    cut = tmp_path / "cut.zmx"
    cut.write_bytes(raw[:(2 * len(raw) // 3) | 1])  # an odd byte count: half a UTF-16 character at the end
    r = _run("optics", "import", cut, "--out", tmp_path / "out")
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(lines) == 1, r.stderr
    assert str(cut) in lines[0] and "the file ends inside a character" in lines[0], lines[0]


def test_short_lens_files_and_a_whole_file_ending_inside_its_image_block_import(tmp_path):
    """The truncation signs never fire on a whole file: a doublet of three surfaces, and DeepLens-style files whose
    image block is the file's last line (the Nikkor with its trailing TOL/MNUM lines removed)."""
    for name in ("Edmund_32-299.zmx", "Apochromat_Doublet.zmx"):
        r = _run("optics", "import", LENSES / "OpticsDatabase" / name, "--out", tmp_path / name)
        assert r.returncode == 0, r.stderr
    raw = (LENSES / "OpticsDatabase" / "Nikon_Nikkor_20mm_f4.zmx").read_bytes().decode("latin-1")
    whole = tmp_path / "no_trailer.zmx"
    whole.write_bytes(raw[:raw.index("\nTOL ") + 1].rstrip("\r\n").encode("latin-1"))  # ends in the image's POPS line
    r = _run("optics", "import", whole, "--out", tmp_path / "whole")
    assert r.returncode == 0, r.stderr


def _signed_index_trace(surfaces):
    """(EFL, ray height at the image) of a unit-height paraxial ray through the written surface table, mirrors
    included, in the signed-index convention (a mirror: n' = -n; the media after it carry the sign; thicknesses as
    written, negative after one reflection: Welford, Aberrations of Optical Systems, sec. 2.4), independent of
    rayoptics' own paraxial model."""
    y, nu, n = 1.0, 0.0, 1.0
    for s in surfaces:
        c = 0.0 if s["radius_mm"] is None else 1.0 / s["radius_mm"]
        n_after = -n if s["mirror"] else math.copysign(s["n"], n)
        nu = nu - y * (n_after - n) * c
        n = n_after
        y = y + s["thickness_mm"] * nu / n
    return -1.0 / nu, y


def _detector_radius_mm(out):
    import tomllib

    scene = tomllib.loads((out / "scene.toml").read_text())
    return next(q for q in scene["part"] if q["name"] == "image")["surface"]["outer_radius_mm"]


def test_a_lens_with_only_an_on_axis_field_gets_a_sensor_sized_detector(tmp_path):
    """CODE V 32327 (a cemented doublet, EFL 100 mm, EPD 25 mm) gives one field, 0 deg: 1.2 x the largest image
    height is 0, and the detector was 1.5 mm across the spot's floor (0.05 x EPD), so ``ghosts`` counted only the
    ghost light within 1.5 mm of the axis (the s3 > s1 ghost, focused 89 mm before the detector: 7.2e-7 W of its
    6.6e-5 W on a sensor of the lens's size). X = the last lens surface's clear aperture (s3, 12 mm in the file):
    the nominal beam and every ghost leave the lens through it, so a sensor that takes them covers at least that;
    the detector is 1.2 x it. A lens with an off-axis field keeps 1.2 x the largest image height (CONTRACTS 8.1)."""
    r = _run("optics", "import", LENSES / "ray-optics" / "CODV_32327.seq", "--out", tmp_path / "a")
    assert r.returncode == 0, r.stderr
    assert ("the file's fields are all on axis (no image height): detector image of radius 14.4 mm, 1.2 x the last "
            "lens surface's clear aperture (s3, 12 mm)") in r.stderr, r.stderr
    doc = json.loads((tmp_path / "a" / "prescription.json").read_text())
    assert doc["fields_deg"] == [0.0]
    last = doc["surfaces"][-1]
    assert last["name"] == "s3" and last["semi_diameter_mm"] == 12.0 and last["glass"] is None
    assert _detector_radius_mm(tmp_path / "a") >= last["semi_diameter_mm"]
    r = _run("optics", "import", LENSES / "ray-optics" / "ag_dblgauss.seq", "--out", tmp_path / "b")
    doc = json.loads((tmp_path / "b" / "prescription.json").read_text())
    assert "all on axis" not in r.stderr and max(doc["fields_deg"]) > 0
    assert math.isclose(_detector_radius_mm(tmp_path / "b"),
                        1.2 * doc["efl_mm"] * math.tan(math.radians(max(doc["fields_deg"]))), rel_tol=1e-6)


def test_an_on_axis_lens_whose_file_sizes_its_image_surface_gets_that_detector(tmp_path):
    """Thorlabs' ACL3026U (one on-axis field) with its image surface's DIAM set to 6 mm (fixed), larger than the
    spot: the detector is 1.2 x that semi-diameter, the file's own sensor. As shipped (DIAM 0.032 mm, OpticStudio's
    automatic spot size) the last lens surface's clear aperture sets it (15 mm: radius 18 mm)."""
    raw = (LENSES / "ray-optics" / "ACL3026U.zmx").read_bytes().decode("utf-16")
    assert raw.count("DIAM 3.245816035765E-2 0 0 0 1") == 1
    lens = tmp_path / "sized.zmx"
    lens.write_text(raw.replace("DIAM 3.245816035765E-2 0 0 0 1", "DIAM 6.0E+0 1 0 0 1"), encoding="utf-16")
    r = _run("optics", "import", lens, "--out", tmp_path / "a")
    assert r.returncode == 0, r.stderr
    assert "1.2 x the image surface's semi-diameter in the file (6 mm)" in r.stderr, r.stderr
    assert math.isclose(_detector_radius_mm(tmp_path / "a"), 7.2, rel_tol=1e-9)
    r = _run("optics", "import", LENSES / "ray-optics" / "ACL3026U.zmx", "--out", tmp_path / "b")
    assert r.returncode == 0, r.stderr
    assert math.isclose(_detector_radius_mm(tmp_path / "b"), 18.0, rel_tol=1e-9)


def _signed_heights(surfaces):
    """The paraxial marginal ray's height on each surface of the written table for a unit height in the entrance
    pupil (the signed-index trace of :func:`_signed_index_trace`, mirrors included)."""
    y, nu, n, heights = 1.0, 0.0, 1.0, []
    for s in surfaces:
        heights.append(y)
        c = 0.0 if s["radius_mm"] is None else 1.0 / s["radius_mm"]
        n_after = -n if s["mirror"] else math.copysign(s["n"], n)
        nu = nu - y * (n_after - n) * c
        n = n_after
        y = y + s["thickness_mm"] * nu / n
    return heights


@pytest.mark.parametrize("name, limit, obscuration, marked", [
    ("Nikon_AI_Reflex-Nikkor_1000mm_f11.zmx", "s6", "s3", 11.0),
    ("Canon_New_FD_500mm_f8_Mirror.zmx", "s5", "s8", 8.0)])
def test_a_file_with_no_aperture_and_no_stop_gets_the_aperture_its_clear_apertures_allow(name, limit, obscuration,
                                                                                         marked, tmp_path):
    """Two reflex lenses whose files give no aperture command and mark no stop imported with rayoptics' 1 mm pupil
    (f/# 1001 and 500). The pupil is now the paraxial limiting aperture: the primary mirror's semi-diameter is the
    first the marginal ray fills (checked against a signed-index y-nu trace of the written table, independent of
    rayoptics; every lens and mirror passes the pupil paraxially). The plane dummy in the incoming beam (air both
    sides, the secondary's outline) is not the limit: the marginal ray passes outside it. Against the names: the
    f-number of a disk of the annular pupil's area (the obscuration's outline mapped into the pupil) is the marked
    f/11 and f/8 within 6 %; the unobscured paraxial f/# is 9.96 and 6.64."""
    r = _run("optics", "import", LENSES / "OpticsDatabase" / name, "--out", tmp_path)
    assert r.returncode == 0, r.stderr
    assert ("the file gives no aperture (ENPD, FNUM, OBNA or FLOA) and no stop is marked: the clear apertures limit the "
            "pupil to") in r.stderr and f"(surface {limit}, " in r.stderr, r.stderr
    doc = json.loads((tmp_path / "prescription.json").read_text())
    surfaces = doc["surfaces"]
    heights = _signed_heights(surfaces)
    by_name = {s["name"]: (s, abs(h)) for s, h in zip(surfaces, heights)}
    s_lim, y_lim = by_name[limit]
    assert math.isclose(doc["epd_mm"], 2 * s_lim["semi_diameter_mm"] / y_lim, rel_tol=1e-6), doc["epd_mm"]
    assert math.isclose(doc["fno"], doc["efl_mm"] / doc["epd_mm"], rel_tol=1e-6), doc["fno"]
    before = 1.0
    for s, h in zip(surfaces, heights):
        if s["mirror"] or s["n"] != before:  # a lens or mirror surface (a dummy keeps the medium)
            assert abs(h) * doc["epd_mm"] / 2 <= s["semi_diameter_mm"] * (1 + 1e-6), s["name"]
        before = s["n"]
    s_obs, y_obs = by_name[obscuration]
    assert s_obs["radius_mm"] is None and abs(y_obs) * doc["epd_mm"] / 2 > s_obs["semi_diameter_mm"]
    d_obs = 2 * s_obs["semi_diameter_mm"] / y_obs
    annulus_fno = doc["efl_mm"] / math.sqrt(doc["epd_mm"] ** 2 - d_obs ** 2)
    assert abs(annulus_fno / marked - 1) < 0.06, annulus_fno


def test_mirrors_written_as_a_medium_of_index_minus_one_are_mirrors(tmp_path):
    """OpticsDatabase's catadioptric lenses write each mirror as refraction into a medium of index -1 of no thickness
    (``GLAS ___BLANK 1 0 -1``). It was read as air: the Reflex-Nikkor-C 500 mm f/8's two Mangin mirrors vanished
    (EFL -224 mm). Read as mirrors inside their glass, its EFL is the signed-index paraxial trace's and its name's,
    500 mm, and the paraxial focus is on the file's image surface."""
    r = _run("optics", "import", LENSES / "OpticsDatabase" / "Nikon_Reflex-Nikkor-C_500mm_F8.zmx", "--out", tmp_path)
    assert r.returncode == 0, r.stderr
    assert "surface(s) 6, 12: a medium of index -1 with no thickness" in r.stderr, r.stderr
    doc = json.loads((tmp_path / "prescription.json").read_text())
    assert [s["name"] for s in doc["surfaces"] if s["mirror"]] == ["s6", "s12"]
    assert {s["glass"] for s in doc["surfaces"] if s["mirror"]} == {"541.472", "548.459"}  # each inside its glass
    efl, y_image = _signed_index_trace(doc["surfaces"])
    assert math.isclose(doc["efl_mm"], efl, rel_tol=1e-6) and abs(doc["efl_mm"] - 500.0) < 0.5, doc["efl_mm"]
    assert abs(y_image) < 1e-4


@pytest.mark.parametrize("edit, words", [
    (("-1  0 0 0", "-1.5  0 0 0"), "surface 6 (line 109): a medium of negative index (nd -1.5, thickness 0)"),
    (("DISZ  -8.8", "DISZ  0"), "surface 6 (line 109): a mirror written as index -1 whose neighbours of no thickness "
                                "(surface 8) differ from it in shape or medium"),
])
def test_a_negative_index_that_is_not_such_a_mirror_is_refused(edit, words, tmp_path):
    text = (LENSES / "OpticsDatabase" / "Nikon_Reflex-Nikkor-C_500mm_F8.zmx").read_bytes().decode("latin-1")
    assert text.count(edit[0]) >= 1
    lens = tmp_path / "edited.zmx"
    lens.write_bytes(text.replace(edit[0], edit[1], 1).encode("latin-1"))
    r = _run("optics", "import", lens, "--out", tmp_path / "out")
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(lines) == 1 and str(lens) in lines[0] and words in lines[0], r.stderr


def test_a_solid_catadioptric_whose_file_ends_inside_the_lens_is_refused(tmp_path):
    """The Vivitar Series 1 450 mm f/4.5 "Solid Mirror" read as EFL 2256 mm: its two mirrors (index -1) were air,
    leaving its front lens alone (f = 1107.79 / 0.491). With them read, the file as written has EFL 352.5 mm, and
    it ends on a lone surface (R 634.3 mm, air on both sides) with the image surface on it, 77.9 mm short of the
    focus: the rear positive and negative groups of its patent (US 4,523,816, claim 1) are not in the file. That
    is refused in one line, not imported as a 352 mm lens under a 450 mm name."""
    lens = LENSES / "OpticsDatabase" / "Vivitar_Series_1_450mm_F4.5_Solid_Mirror.zmx"
    r = _run("optics", "import", lens, "--out", tmp_path / "out")
    lines = [ln for ln in r.stderr.splitlines() if ln.strip() and not ln.startswith("warning:")]
    assert r.returncode == 2 and len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert str(lens) in lines[0], lines[0]
    assert ("the image surface is on surface 9 (R 634.3 mm, no distance between) but the lens as written focuses "
            "77.88 mm from it (EFL 352.5 mm): the file ends before the lens does") in lines[0], lines[0]


def _y_at(surfaces, k):
    """Paraxial marginal ray height at the table's surface after its first ``k`` for a unit ray height on the first
    (y-nu: n'u' = nu - y (n' - n) c, y' = y + t u)."""
    y, nu, n = 1.0, 0.0, 1.0
    for s in surfaces[:k]:
        c = 0.0 if s["radius_mm"] is None else 1.0 / s["radius_mm"]
        nu = nu - y * (s["n"] - n) * c
        n = s["n"]
        y = y + s["thickness_mm"] * nu / n
    return y


def test_a_pupil_floating_by_stop_size_fills_the_stop(tmp_path):
    """Zemax FLOA: the entrance pupil is what the stop's semi-diameter lets through. optiland's lens_floa.zmx (a
    singlet, the stop 10 mm behind it, semi-diameter 8.5 mm): EPD = 2 x 8.5 / the marginal ray's height at the
    stop per unit height in the pupil, from a y-nu trace of the written table. A DIAM line with the semi-diameter
    alone (as hand-written files have it) reads the same."""
    r = _run("optics", "import", LENSES / "optiland" / "lens_floa.zmx", "--out", tmp_path / "a")
    assert r.returncode == 0, r.stderr
    assert "aperture floats by stop size (FLOA)" in r.stderr
    doc = json.loads((tmp_path / "a" / "prescription.json").read_text())
    assert math.isclose(doc["epd_mm"], 2 * 8.5 / abs(_y_at(doc["surfaces"], 2)), rel_tol=1e-6)
    bare = tmp_path / "bare.zmx"
    bare.write_text((LENSES / "optiland" / "lens_floa.zmx").read_text().replace('DIAM 8.5 1 0 0 1 ""', "DIAM 8.5"))
    r = _run("optics", "import", bare, "--out", tmp_path / "b")
    assert r.returncode == 0, r.stderr
    assert json.loads((tmp_path / "b" / "prescription.json").read_text())["epd_mm"] == doc["epd_mm"]


@pytest.mark.parametrize("name, fno, words", [
    ("Nikon_Nikkor_20mm_f4.zmx", 4.0, "aperture floats by stop size (FLOA)"),
    ("Canon_EF16-35mm_f2.8L_III_USM.zmx", 2.8, "aperture floats by stop size (FLOA)"),
    ("Samsung_18-55mm_F3.5-5.6_OIS_III.zmx", 3.5, "the file gives no aperture (ENPD, FNUM, OBNA or FLOA)")])
def test_a_camera_lens_floating_by_stop_size_has_its_marked_f_number(name, fno, words, tmp_path):
    """Bill Claff's conversions of patents set the aperture by the stop's size (FLOA), or give no aperture
    command at all: the paraxial f/# is the lens's marked one within 5 % (before, rayoptics' default 1 mm pupil
    gave f/# = efl in mm)."""
    r = _run("optics", "import", LENSES / "OpticsDatabase" / name, "--out", tmp_path)
    assert r.returncode == 0, r.stderr
    assert words in r.stderr
    doc = json.loads((tmp_path / "prescription.json").read_text())
    assert abs(doc["fno"] / fno - 1) < 0.05, doc["fno"]


def test_extended_aspheres_with_even_terms_are_even_aspheres(tmp_path):
    """Zemax XASPHERE terms from r^4 on, as PARM lines (Canon EF 16-35, surface 1: PARM 2 = 1.16240e-05 the r^4
    term...) or as extra data (Ricoh GR 6.0 mm, surface 7: XDAT 4 = the rho^4 term, normalising radius 1)."""
    r = _run("optics", "import", LENSES / "OpticsDatabase" / "Canon_EF16-35mm_f2.8L_III_USM.zmx", "--out", tmp_path / "c")
    assert r.returncode == 0, r.stderr
    s1 = json.loads((tmp_path / "c" / "prescription.json").read_text())["surfaces"][0]
    assert s1["type"] == "asphere" and s1["coefficients"][:3] == pytest.approx([1.16240e-05, -1.43464e-08, 1.53911e-11])
    r = _run("optics", "import", LENSES / "OpticsDatabase" / "Ricoh_6.0mm_F1.9_VC_GR.zmx", "--out", tmp_path / "r")
    assert r.returncode == 0, r.stderr
    text = (LENSES / "OpticsDatabase" / "Ricoh_6.0mm_F1.9_VC_GR.zmx").read_text()
    surfs = json.loads((tmp_path / "r" / "prescription.json").read_text())["surfaces"]
    import re

    block = text.split("SURF ")[[i for i, b in enumerate(text.split("SURF ")) if "XASPHERE" in b][0]]
    idx = int(block.split()[0])
    a4 = float(re.search(r"XDAT 4 (\S+)", block).group(1))
    s = next(x for x in surfs if x["name"] == f"s{idx}")
    assert s["type"] == "asphere" and s["coefficients"][0] == pytest.approx(a4)


def test_a_glass_the_catalogues_lack_is_read_from_the_zemax_glass_line(tmp_path):
    """A Zemax GLAS line carries nd and vd after the name: a name no catalogue has is that model glass, warned."""
    lens = tmp_path / "g.zmx"
    lens.write_text((LENSES / "optiland" / "lens_floa.zmx").read_text().replace("GLAS N-BK7", "GLAS NOSUCHGLASS"))
    r = _run("optics", "import", lens, "--out", tmp_path / "out")
    assert r.returncode == 0, r.stderr
    assert "glass NOSUCHGLASS is not in the catalogues: read from the file's own nd 1.5168, vd 64.17" in r.stderr
    doc = json.loads((tmp_path / "out" / "prescription.json").read_text())
    assert abs(doc["surfaces"][0]["n"] - 1.5168) < 1e-4  # 587.6 nm: the d line of the model glass
    # a model glass given by nd alone (rayoptics failed on it: IndexError): a constant index, as Zemax reads vd 0
    lens.write_text((LENSES / "optiland" / "lens_floa.zmx").read_text().replace("GLAS N-BK7 1 0 1.5168 64.17",
                                                                                 "GLAS ___BLANK 1 0 1.6"))
    r = _run("optics", "import", lens, "--out", tmp_path / "nd")
    assert r.returncode == 0, r.stderr
    assert json.loads((tmp_path / "nd" / "prescription.json").read_text())["surfaces"][0]["n"] == 1.6


def test_real_image_height_fields_rayoptics_cannot_aim_are_read_as_paraxial_heights(tmp_path):
    r = _run("optics", "import", LENSES / "OpticsDatabase" / "Zeiss_Flektogon_20mm_F4.zmx", "--out", tmp_path)
    assert r.returncode == 0, r.stderr
    assert "fields read as paraxial image heights" in r.stderr
    doc = json.loads((tmp_path / "prescription.json").read_text())
    assert abs(doc["fno"] / 4.0 - 1) < 0.05 and abs(doc["efl_mm"] / 20.0 - 1) < 0.05


def test_codev_asphere_terms_without_a_profile_type_are_an_even_asphere(tmp_path):
    """optiland's asphere.seq gives surface 1 ``K -0.5``, ``A 1.5E-6``, ``B -2.3E-9`` and no ``ASP`` (rayoptics
    failed on it): read as that even asphere, warned. Its EFL is the thick lens's (R 50 / -80 mm, 5 mm, the
    model glass nd 1.5168): 1/f = (n - 1) (1/R1 - 1/R2 + (n - 1) t / (n R1 R2))."""
    r = _run("optics", "import", LENSES / "optiland" / "asphere.seq", "--out", tmp_path)
    assert r.returncode == 0, r.stderr
    assert "conic or asphere terms without a profile type" in r.stderr
    doc = json.loads((tmp_path / "prescription.json").read_text())
    s1 = doc["surfaces"][0]
    assert (s1["type"], s1["conic"], s1["coefficients"]) == ("asphere", -0.5, [1.5e-6, -2.3e-9])
    n, R1, R2, t = s1["n"], 50.0, -80.0, 5.0
    assert math.isclose(doc["efl_mm"], 1 / ((n - 1) * (1 / R1 - 1 / R2 + (n - 1) * t / (n * R1 * R2))), rel_tol=1e-6)


def test_a_semi_diameter_past_the_spheres_rim_ends_inside_it(tmp_path):
    """The Canon EF 15 mm fisheye file gives its front meniscus's back (R 15.9 mm) a semi-diameter of 16.21 mm,
    past the hemisphere's rim, where the sphere has no sag (the scene refused the part). The clear aperture
    ends at 0.999 R, warned, and the scene loads."""
    from straylight.scene import load_scene

    r = _run("optics", "import", LENSES / "OpticsDatabase" / "Canon_EF15mm_f2.8_Fisheye.zmx", "--out", tmp_path)
    assert r.returncode == 0, r.stderr
    assert "s2: semi-diameter 16.21 mm reaches past the surface's rim (radius 15.9 mm" in r.stderr
    doc = json.loads((tmp_path / "prescription.json").read_text())
    assert doc["surfaces"][1]["semi_diameter_mm"] == pytest.approx(0.999 * 15.9)
    load_scene(tmp_path / "scene.toml")


def test_extended_odd_aspheres_are_read_with_their_power_terms(tmp_path):
    """Zemax XOSPHERE (extended odd asphere: XDAT 1 the number of terms, XDAT 2 the normalising radius, XDAT 3 +
    k the rho^(k + 1) term) as the scene's ``asphere`` with ``power_terms``: the Fujinon XF27mm F2.8's surface 13,
    whose r^3 and r^5 terms are read from the file here, and its sag matches the file's formula term by term."""
    import re

    lens = LENSES / "OpticsDatabase" / "Fujifilm_Fujinon_XF27mm_F2.8.zmx"
    r = _run("optics", "import", lens, "--out", tmp_path)
    assert r.returncode == 0, r.stderr
    text = lens.read_text()
    blocks = {int(b.split()[0]): b for b in text.split("SURF ")[1:]}
    idx = min(i for i, b in blocks.items() if "XOSPHERE" in b)
    xdat = {int(k): float(v) for k, v in re.findall(r"XDAT (\d+) (\S+)", blocks[idx])}
    assert xdat[2] == 1.0  # normalising radius 1: the coefficients are the terms
    surf = next(s for s in json.loads((tmp_path / "prescription.json").read_text())["surfaces"] if s["name"] == f"s{idx}")
    terms = dict((p, a) for p, a in surf["power_terms"])
    assert terms[3] == pytest.approx(xdat[5]) and terms[5] == pytest.approx(xdat[7])
    assert surf["coefficients"][0] == pytest.approx(xdat[6])  # the r^4 term stays an even coefficient
    import math as m

    from straylight.optics.sag import sag_mm

    class S:  # the file's own formula, term by term
        radius_mm = surf["radius_mm"]
        conic = surf["conic"]
        coefficients: list = []
        power_terms = [(k - 2, v) for k, v in xdat.items() if k >= 3 and k - 2 <= int(xdat[1])]
    rho = 0.9 * surf["semi_diameter_mm"]
    c = 1.0 / surf["radius_mm"]
    ref = c * rho * rho / (1 + m.sqrt(1 - (1 + surf["conic"]) * c * c * rho * rho)) + sum(
        v * rho ** p for p, v in S.power_terms)
    assert sag_mm(S, rho) == pytest.approx(ref, rel=1e-12)
    scene = (tmp_path / "scene.toml").read_text()
    assert "power_terms = [[3, " in scene


def test_zemax_odd_asphere_type_is_read(tmp_path):
    """Zemax ODDASPHE (``PARM k`` the r^k term): a corpus lens's first surface turned into one, written here."""
    src = (LENSES / "optiland" / "lens1.zmx").read_text(encoding="utf-8", errors="replace")
    import re

    m = re.search(r"(SURF 1\s*\n)(\s*)TYPE STANDARD", src)
    assert m, "lens1.zmx's surface 1 is a STANDARD surface"
    odd = src[:m.start()] + m.group(1) + m.group(2) + "TYPE ODDASPHE\n" + m.group(2) + "PARM 1 0\n" + m.group(2) \
        + "PARM 2 0\n" + m.group(2) + "PARM 3 2.5E-05\n" + m.group(2) + "PARM 5 -1.0E-08" + src[m.end():]
    (tmp_path / "odd.zmx").write_text(odd, encoding="utf-8")
    r = _run("optics", "import", tmp_path / "odd.zmx", "--out", tmp_path / "o")
    assert r.returncode == 0, r.stderr
    s1 = json.loads((tmp_path / "o" / "prescription.json").read_text())["surfaces"][0]
    assert s1["type"] == "asphere" and s1["power_terms"] == [[3, pytest.approx(2.5e-05)], [5, pytest.approx(-1.0e-08)]]


def test_an_r2_term_on_a_flat_base_is_the_paraboloid_it_is(tmp_path):
    """The Canon EF 50mm f/1.0's surfaces 5 and 15: flat, with EVENASPH r^2 terms (PARM 1 = 7.358E-03 and
    -7.396E-03): z = a2 rho^2 is the paraboloid c = 2 a2, k = -1, so the paraxial data see its power (EFL
    ~52 mm for the 50 mm lens; 93.7 mm when the term was left to the polynomial)."""
    r = _run("optics", "import", LENSES / "OpticsDatabase" / "Canon_EF50mm_f1.0L_USM.zmx", "--out", tmp_path)
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / "prescription.json").read_text())
    s5 = next(s for s in doc["surfaces"] if s["name"] == "s5")
    assert s5["conic"] == -1.0 and s5["radius_mm"] == pytest.approx(1.0 / (2 * 7.358e-03), rel=1e-9)
    assert "power_terms" not in s5
    assert 50.0 < doc["efl_mm"] < 54.0


def _scene_parts_at_z(scene_toml: Path, z_mm: float) -> list:
    import tomllib

    doc = tomllib.loads(scene_toml.read_text(encoding="utf-8"))
    return doc, [pt for pt in doc["part"] if pt["surface"]["type"] not in ("cylinder",)
                 and abs(pt["surface"]["vertex_mm"][2] - z_mm) < 1e-6]


def test_two_glasses_in_contact_are_one_interface_between_them(tmp_path):
    """OpticsDatabase's Samyang 50mm F1.4 AS UMC: s4 (from glass nd 1.846663 into air, no thickness after it) and
    s5 (from air into glass nd 1.717360) have one shape (CURV 0.0296357763091604): two elements that touch. The
    second was dropped as the first met again, so the second element was air and the imported lens focused
    nowhere near the file's image (ghosts' nominal image 2.6 mm RMS). Now one part between the two glasses, with
    the file's nd (the reference wavelength, 587.6 nm, is the d line to 1e-4 in n), and the rest of the air gap
    nowhere."""
    r = _run("optics", "import", LENSES / "OpticsDatabase" / "Samyang_50mm_F1.4_AS_UMC.zmx", "--out", tmp_path)
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / "prescription.json").read_text())
    s4 = next(s for s in doc["surfaces"] if s["name"] == "s4")
    z4 = sum(s["thickness_mm"] for s in doc["surfaces"][:3])  # s1's vertex at the origin
    scene, parts = _scene_parts_at_z(tmp_path / "scene.toml", z4)
    assert s4["thickness_mm"] == 0.0
    assert len(parts) == 1, [pt["name"] for pt in parts]
    comp = scene["material"][parts[0]["material"]]["components"][0]
    assert comp["type"] == "dielectric"
    assert sorted([comp["n"], comp["n_outside"]]) == [pytest.approx(1.717360, abs=1e-4), pytest.approx(1.846663, abs=1e-4)]
    assert "two glasses in contact" in r.stderr


_STOP_FIRST_ZMX = """VERS 190513 80 123457 L123457
MODE SEQ
NAME stop in front
UNIT MM X W X CM MR CPMM
ENPD 20
WAVM 1 0.55 1
PWAV 1
XFLN 0 0
YFLN 0 5
FTYP 0 0 2 1 0 0 0
GCAT SCHOTT
SURF 0
  TYPE STANDARD
  CURV 0.0
  DISZ INFINITY
SURF 1
  STOP
  COMM {c1}
  TYPE STANDARD
  CURV 0.0
  DISZ 5
  DIAM 10 1 0 0 1 ""
SURF 2
  COMM {c2}
  TYPE STANDARD
  CURV 0.01
  DISZ 6
  GLAS N-BK7 0 0 1.5168 64.17 0 0 0 0 0 0
  DIAM 14 1 0 0 1 ""
SURF 3
  COMM {c3}
  TYPE STANDARD
  CURV -0.004
  DISZ 90
  DIAM 14 1 0 0 1 ""
SURF 4
  TYPE STANDARD
  CURV 0.0
  DISZ 0
"""


def test_a_zemax_stop_on_surface_1_and_its_comments_name_the_parts(tmp_path):
    """A STOP on the first surface (rayoptics' reader drops it: it sets a stop only from the third surface on)
    gives the black `stop` part, its hole the stop's semi-diameter; unique comments name their surfaces'
    parts (CONTRACTS 8.1), but never a name the builder uses or another surface's default name."""
    import tomllib

    lens = tmp_path / "stop_first.zmx"
    lens.write_text(_STOP_FIRST_ZMX.format(c1="aperture", c2="front", c3="back"))
    r = _run("optics", "import", lens, "--out", tmp_path / "a")
    assert r.returncode == 0, r.stderr
    parts = {p["name"]: p for p in tomllib.loads((tmp_path / "a" / "scene.toml").read_text())["part"]}
    assert {"front", "back", "stop"} <= set(parts)
    assert parts["stop"]["surface"]["inner_radius_mm"] == pytest.approx(10.0)
    info = _run("optics", "info", lens)
    assert info.returncode == 0 and " stop" in info.stdout
    lens.write_text(_STOP_FIRST_ZMX.format(c1="image", c2="s3", c3="back side"))
    r = _run("optics", "import", lens, "--out", tmp_path / "b")
    assert r.returncode == 0, r.stderr
    doc = tomllib.loads((tmp_path / "b" / "scene.toml").read_text())
    names = [p["name"] for p in doc["part"]]
    assert "s2" in names and "s3" in names and names.count("image") == 1
    assert doc["analysis"]["detector"] == "image"
    assert next(p for p in doc["part"] if p["name"] == "image")["role"] == "detector"


@pytest.mark.parametrize("line, bad, says", [
    ("DISZ 6", "  DISZ abc", "DISZ 'abc' is not a number"),
    # OpticsDatabase's Ricoh smc Pentax Reflex 400-600mm, line 161: the reader's "could not convert string to float"
    ("GLAS N-BK7 0 0 1.5168 64.17 0 0 0 0 0 0", "  GLAS ___BLANK 1 0 1.00000 hack 0 0 0 0 0 0",
     "GLAS ___BLANK has 'hack' for a number"),
])
def test_a_word_for_a_number_in_a_zemax_file_is_refused_naming_its_line(line, bad, says, tmp_path):
    text = _STOP_FIRST_ZMX.format(c1="a", c2="b", c3="c")
    lines = text.splitlines()
    k = next(i for i, x in enumerate(lines) if x.strip() == line)
    lines[k] = bad
    lens = tmp_path / "word.zmx"
    lens.write_text("\n".join(lines) + "\n")
    for cmd in (("optics", "import", lens, "--out", tmp_path / "o"), ("optics", "info", lens)):
        r = _run(*cmd)
        err = [ln for ln in r.stderr.splitlines() if ln.strip()]
        assert r.returncode == 2 and len(err) == 1, r.stderr
        assert str(lens) in err[0] and f"line {k + 1}: {says}" in err[0], err[0]


@pytest.mark.parametrize("object_mm, refused", [("49.85", True), ("1.00E+10", False)])
def test_a_macro_lens_whose_configuration_1_sets_a_near_object_is_refused(object_mm, refused, tmp_path):
    """A multi-configuration file whose surface data keep the object at infinity while configuration 1's
    THIC 0 operand sets it near (OpticsDatabase's macro lenses: the import was a defocused lens, 0.85 of
    the focus check) is refused as a finite object is; an operand at 1e10 is infinity."""
    lens = tmp_path / "macro.zmx"
    lens.write_text(_STOP_FIRST_ZMX.format(c1="a", c2="b", c3="c")
                    + f"MNUM 2 1\nTHIC   0   1 {object_mm} 0 0 0 1 1 1 0 0\nTHIC   0   2 80.0 0 0 0 1 1 1 0 0\n")
    r = _run("optics", "import", lens, "--out", tmp_path / "o")
    if refused:
        assert r.returncode == 2 and "object at a finite distance (49.85 mm, configuration 1" in r.stderr, r.stderr
    else:
        assert r.returncode == 0, r.stderr


def test_fold_mirrors_rayoptics_cannot_group_into_elements_still_import(tmp_path):
    """rayoptics' part-tree grammar refuses some fold-mirror layouts ("ParseError: Rule 'image' didn't match"),
    after the sequential data are read: the import does not need the element grouping. Here the grouping is
    made to refuse a singlet, as it refuses optiland's simple_fold_mirror_up.zmx (MIT; not in tests/data: it
    imports now, and focuses at 1.00 in benchmarks/ghost_sweep.py's check)."""
    from rayoptics.elem import parttree

    calls = []
    grouping = parttree.sequence_to_elements

    def refusing(*args, **kwargs):
        calls.append(1)
        from parsimonious.exceptions import ParseError

        raise ParseError("paparapapad", 12)

    lens = tmp_path / "s.zmx"
    lens.write_text(_STOP_FIRST_ZMX.format(c1="a", c2="b", c3="c"))
    parttree.sequence_to_elements = refusing
    try:
        r = _run("optics", "import", lens, "--out", tmp_path / "o")
    finally:
        parttree.sequence_to_elements = grouping
    assert calls and r.returncode == 0, r.stderr
    assert parttree.sequence_to_elements is grouping


def test_a_codev_glass_of_a_catalogue_the_reader_lacks_is_looked_up_by_name_or_given(tmp_path):
    """``CAF2_DAIMON-20`` (optiland's telescope_objective.seq, MIT): rayoptics' CODE V reader stopped at the
    unknown catalogue ("could not parse it (GlassCatalogNotFoundError: DAIMON-20)"); it is looked up as CAF2
    (a note says so) and --glass with the name as written gives its index."""
    lens = tmp_path / "daimon.seq"
    lens.write_text("RDM\nLEN \"catalogue test\"\nEPD 10\nDIM M\nWL 587.56\nYAN 0 1\nSO 0 1e10\n"
                    "S 60 4 CAF2_DAIMON-20\nSTO\nS -60 55\nSI 0 0\nGO\n")
    r = _run("optics", "import", lens, "--out", tmp_path / "a")
    assert r.returncode == 0, r.stderr
    assert "catalogue DAIMON-20 is not one the reader knows; looked up as CAF2" in r.stderr
    r = _run("optics", "import", lens, "--out", tmp_path / "b", "--glass", "CAF2_DAIMON-20=1.6")
    assert r.returncode == 0, r.stderr
    surfaces = json.loads((tmp_path / "b" / "prescription.json").read_text())["surfaces"]
    assert surfaces[0]["n"] == pytest.approx(1.6)


def test_the_barrel_keeps_the_source_from_passing_around_the_lens(tmp_path):
    """The pupil source is 1.1 x the largest clear aperture and the singlet's image (fields to 5 deg) is larger
    than the lens: without the barrel's front face and tube the source's outer ring reached the image straight
    (here 10 % of the image's power; OpticsDatabase's Fujinon-SW 65 mm: 48 %). With them nothing does."""
    import tomllib

    lens = tmp_path / "singlet.zmx"  # fields to 20 deg: an image of ~60 mm behind a 14 mm lens
    lens.write_text(_STOP_FIRST_ZMX.format(c1="a", c2="front", c3="back").replace("YFLN 0 5", "YFLN 0 20"))
    assert _run("optics", "import", lens, "--out", tmp_path / "s").returncode == 0
    names = [p["name"] for p in tomllib.loads((tmp_path / "s" / "scene.toml").read_text())["part"]]
    assert "barrel_front" in names and "barrel" in names
    r = _run("paths", tmp_path / "s" / "scene.toml", "--angle-deg", "0", "--rays", "4000", "--out", tmp_path / "p")
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / "p" / "paths.json").read_text())
    assert doc["total_w"] > 0 and doc["ancestry"]["direct"]["fraction"] == 0.0


def test_the_stop_ring_stands_in_front_of_a_concave_stop_mirror_out_to_its_edge():
    """optiland's mirror.seq: the stop is a concave mirror (hole 10 mm, clear aperture 10.5 mm). Its ring stood 0.01 mm
    in front of the mirror's sag at the hole, but the rim (sag 0.276 mm at 10.5 mm against 0.250) and its facets
    reach past that plane toward the light: 8 % of the rays on the image came from 10.0-10.5 mm, outside the stop,
    and the encircled power read 0.510 against the sequential 0.561 (0.558 now)."""
    from straylight.optics.reader import read_prescription
    from straylight.optics.scene_build import STOP_CLEARANCE_MM, build_scene
    from straylight.optics.sag import sag_mm

    p = read_prescription(LENSES / "optiland" / "mirror.seq")
    stop = next(s for s in p.surfaces if s.stop)
    ring = next(part for part in build_scene(p)["part"] if part["name"] == "stop")["surface"]
    toward = np.asarray(ring["axis"], float)
    hole = ring["inner_radius_mm"]
    assert stop.mirror and stop.semi_diameter_mm > hole
    rho = np.linspace(hole, stop.semi_diameter_mm, 50)
    ahead = (np.asarray(ring["vertex_mm"]) - stop.vertex_mm) @ toward - sag_mm(stop, rho) * float(stop.local_z @ toward)
    assert ahead.min() >= STOP_CLEARANCE_MM - 1e-9, ahead.min()


def test_no_light_passes_beside_the_stop_of_a_double_gauss(tmp_path):
    """US 2532751 (DiffOptics' double Gauss example): the stop's ring reached 1.5 x its 2.44 mm hole, and between
    the elements (clear apertures 4.5-8.7 mm) light went around it: with the hole closed, 0.079 W of the 0.186 W
    on the image still arrived. The ring now reaches the barrel's tube; closed, nothing arrives."""
    import tomllib

    from straylight.cli.main import main
    from straylight.scene import load_scene

    assert main(["optics", "import", str(LENSES / "DiffOptics" / "US02532751-1.zmx"), "--out", str(tmp_path)]) == 0
    text = (tmp_path / "scene.toml").read_text()
    scene = tomllib.loads(text)
    ring = next(part for part in scene["part"] if part["name"] == "stop")["surface"]
    barrel = next(part for part in scene["part"] if part["name"] == "barrel")["surface"]
    assert ring["outer_radius_mm"] >= barrel["radius_mm"]
    closed = text.replace(f"inner_radius_mm = {ring['inner_radius_mm']!r}", "inner_radius_mm = 0.0", 1)
    assert closed != text
    (tmp_path / "closed.toml").write_text(closed)
    assert load_scene(tmp_path / "closed.toml").trace(20000, seed=2).detectors["image"].power_w == 0.0
    assert load_scene(tmp_path / "scene.toml").trace(20000, seed=2).detectors["image"].power_w > 0.05


def test_a_non_sequential_zemax_file_is_refused_in_one_line(tmp_path, capsys):
    """A MODE NSC file (ZOSPy's eye models, skZemax's e02) reached rayoptics, whose parser failed with a
    ZeroDivisionError: the user read "could not parse it". It is refused as what it is."""
    from straylight.cli.main import main

    lens = tmp_path / "nsc.zmx"
    lens.write_text("VERS 190513 80 123457\nMODE NSC\nNAME eye\nUNIT MM X W X CM MR CPMM\nSURF 0\n  TYPE STANDARD\n"
                    "  CURV 0.0\n  DISZ INFINITY\nSURF 1\n  TYPE NONSEQCO\n  DISZ 0\nSURF 2\n  TYPE STANDARD\n")
    for command in (["optics", "import", str(lens), "--out", str(tmp_path / "out")], ["optics", "info", str(lens)]):
        capsys.readouterr()
        assert main(command) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "non-sequential Zemax file (MODE NSC)" in err[0], err
    assert not (tmp_path / "out" / "scene.toml").exists()


def test_a_coordinate_break_inside_a_prism_keeps_its_glass(tmp_path):
    """ZOSPy's TIR prism: a coordinate break (s9) inside the BK7 tilts the reflecting face (s10, MIRROR), another
    (s11) turns the axis after it. A break has no material: Zemax keeps the medium across it, and rayoptics read
    air after it, so the prism's glass ended at s9, which became a glass-air face, the reflection happened in air,
    and `optics import` wrote a scene that refused to load (s9's 1 mm face inside the 86.6 mm centre the mirror,
    met again there, leaves: inner_radius_mm 86.59 must be < outer_radius_mm 1). Now the breaks are dummies in
    the glass, the face reflects inside it, and the scene traces."""
    from straylight.cli.main import main
    from straylight.optics.reader import read_prescription
    from straylight.scene import load_scene

    lens = LENSES / "ZOSPy" / "Prism_using_total_internal_reflection.zmx"
    p = read_prescription(lens)
    by_name = {s.name: s for s in p.surfaces}
    n_bk7 = by_name["s8"].n
    assert n_bk7 > 1.5
    assert by_name["s9"].dummy and by_name["s9"].n_before == by_name["s9"].n == n_bk7
    assert by_name["s10"].mirror and by_name["s10"].n_before == n_bk7 and by_name["s12"].n == 1.0
    assert any("coordinate break(s) 9, 11 inside a medium" in w for w in p.warnings), p.warnings
    assert main(["optics", "import", str(lens), "--out", str(tmp_path)]) == 0
    assert load_scene(tmp_path / "scene.toml").trace(4000, seed=1).detectors["image"].power_w > 0


def test_a_part_covered_whole_by_another_surface_s_centre_is_left_out():
    """A surface whose whole aperture lies inside the centre another surface met again leaves to it covers
    nothing: it gets no part (warned), never a part whose hole is wider than itself (a scene that cannot load)."""
    from types import SimpleNamespace

    from straylight.optics.scene_build import _without_empty_annuli

    p = SimpleNamespace(warnings=[])
    parts = [{"name": "s9", "surface": {"type": "plane", "outer_radius_mm": 1.0, "inner_radius_mm": 86.59}},
             {"name": "s10", "surface": {"type": "plane", "outer_radius_mm": 100.0, "inner_radius_mm": 1.0}},
             {"name": "edge", "surface": {"type": "cylinder", "radius_mm": 5.0, "length_mm": 1.0}}]
    assert [part["name"] for part in _without_empty_annuli(p, parts)] == ["s10", "edge"]
    assert len(p.warnings) == 1 and p.warnings[0].startswith("s9: its whole aperture (1 mm)")


def _negative_singlet_zmx() -> str:
    """A biconcave N-BK7 singlet (R -50 / +50 mm, 3 mm thick, EFL ~ -48 mm), its image surface at its virtual
    image 47.5 mm before its back: the window of test_optics_window_ghosts with curved faces."""
    from test_optics_window_ghosts import ZMX as WINDOW_ZMX

    text = WINDOW_ZMX.replace("  CURV 0.0\n  DISZ 5\n", "  CURV -0.02\n  DISZ 3\n")
    text = text.replace("  CURV 0.0\n  DISZ 10\n", "  CURV 0.02\n  DISZ -47.5\n")
    assert text.count("CURV -0.02") == 1 and text.count("DISZ -47.5") == 1
    return text


def test_a_diverging_lens_gets_its_detector_behind_it(tmp_path):
    """A biconcave singlet (EFL ~ -48 mm) whose file puts the image surface at its virtual image, in front of the
    lens (Thorlabs' ACN254-100-A and LD2568-A so): the detector stood there, behind the source, and `ghosts` found
    no ray reaching it. Now it is a plane |EFL| behind the last surface, wide enough for the diverging beam
    (1.2 x (2 x the largest clear aperture + 0)), warned; the beam and the lens's one ghost reach it."""
    import tomllib

    from straylight.analyses.ghost_trace import ghosts
    from straylight.cli.main import main

    lens = tmp_path / "biconcave.zmx"
    lens.write_text(_negative_singlet_zmx())
    assert main(["optics", "import", str(lens), "--out", str(tmp_path / "out")]) == 0
    doc = json.loads((tmp_path / "out" / "prescription.json").read_text())
    assert doc["efl_mm"] < 0 and any("diverging lens" in w for w in doc["warnings"]), doc["warnings"]
    scene = tomllib.loads((tmp_path / "out" / "scene.toml").read_text())
    det = next(part for part in scene["part"] if part["name"] == "image")["surface"]
    last_z = max(part["surface"]["vertex_mm"][2] for part in scene["part"] if part["name"] in ("s1", "s2"))
    assert det["vertex_mm"][2] == pytest.approx(last_z + abs(doc["efl_mm"]), abs=1e-6)
    assert det["outer_radius_mm"] >= 1.2 * 2 * 12.0
    table = ghosts(tmp_path / "out" / "scene.toml", order=2, seed=1, target_rel_error=0.05)
    assert table.nominal.power_w > 0.5 and len(table.rows) == 1 and table.rows[0].power_w > 0


def test_an_immersed_image_is_refused_as_such_not_as_a_file_cut_short(tmp_path, capsys):
    """A microscope objective imaging into water behind a cover glass (m-d-young's COTS objectives): the image
    surface carries the medium before it. The file is whole, but it was refused as cut short ("no image surface").
    Now it is refused as what it is: an immersed image, which the import does not model."""
    from straylight.cli.main import main

    text = _negative_singlet_zmx().replace("CURV 0.02\n  DISZ -47.5\n", "CURV 0.0\n  DISZ 20\n  GLAS F2 1 0 1.62004 36.37\n")
    text = text.replace("SURF 3\n  TYPE STANDARD\n  CURV 0.0\n  DISZ 0\n",
                        "SURF 3\n  TYPE STANDARD\n  CURV 0.0\n  DISZ 0\n  GLAS F2 1 0 1.62004 36.37\n")
    lens = tmp_path / "immersed.zmx"
    lens.write_text(text)
    capsys.readouterr()
    assert main(["optics", "import", str(lens), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "an immersed image" in err[0] and "cut short" not in err[0], err


def test_a_codev_title_naming_a_zoom_position_is_no_zoom_qualifier(tmp_path):
    """opticspy's XF_HW3_PB2.seq: rayoptics read ``TITLE 'Z1 decenter 0'`` (and a zoom's ``TIT Z1 "..."`` lines) as
    zoom qualifiers and failed (IndexError: "could not parse it"). Titles are not read now; the zoom's first
    position is imported, warned with the file's number of positions."""
    from straylight.cli.main import main

    body = (LENSES / "ray-optics" / "landscape_lens.seq").read_text().replace("tit 'Landscape lens'",
                                                                              "TITLE 'Z1   decenter 0'")
    zoomed = body.replace("dim m", "dim m\nZOO 3\nZOO TIT\nTIT Z1 \"Z1 a\"\nTIT Z2 \"Z2 b\"\nTIT Z3 \"Z3 c\"", 1)
    for name, text in (("titled.seq", body), ("zoomed.seq", zoomed)):
        lens = tmp_path / name
        lens.write_text(text)
        assert main(["optics", "import", str(lens), "--out", str(tmp_path / name[:-4])]) == 0, name
    doc = json.loads((tmp_path / "zoomed" / "prescription.json").read_text())
    assert any("3 configurations" in w for w in doc["warnings"]), doc["warnings"]


def test_a_glass_rayoptics_found_nothing_for_is_no_substitution():
    """rayoptics' substitution map also counts the glass names it found nothing for ({"LITHOTEC-CAF2": 2}); the
    import warned "rayoptics substituted 2" for a glass it then read as CaF2 itself. Only real substitutions are
    warned."""
    from straylight.optics.reader import _substitutions

    notes = _substitutions((None, {"N-FK51": ("N-FK51A", "Schott"), "LITHOTEC-CAF2": 2}))
    assert notes == ["glass N-FK51 is not in the catalogues as written; rayoptics substituted N-FK51A (Schott)"]


def test_an_unknown_glass_is_named_with_the_surfaces_that_give_no_index(tmp_path):
    """YuryStrelkov's F07g04 Cassegrain: glass LZ_K8 on four surfaces, three of whose GLAS lines carry its nd, one
    (surface 57) nd 1. The refusal named the glass only, not where the file gives no index. (--glass NAME=N, as
    CONTRACTS 8.1 has it, then gives every surface of that glass N.)"""
    from test_optics_window_ghosts import ZMX as WINDOW_ZMX

    text = WINDOW_ZMX.replace("  GLAS N-BK7 1 0 1.5168 64.17\n", "  GLAS MYGLASS 1 0 1.6 40\n")
    text = text.replace("  DISZ 10\n", "  DISZ 10\n  GLAS MYGLASS 1 0 1 0\n", 1)
    text = text.replace("SURF 3\n", "SURF 3\n  TYPE STANDARD\n  CURV 0.0\n  DISZ 5\nSURF 4\n", 1)
    lens = tmp_path / "lens.zmx"
    lens.write_text(text)
    r = _run("optics", "import", lens, "--out", tmp_path / "a")
    assert r.returncode == 2 and "unknown glass MYGLASS after surface(s) 2 " in r.stderr, r.stderr
    r = _run("optics", "import", lens, "--glass", "MYGLASS=1.7", "--out", tmp_path / "b")
    assert r.returncode == 0, r.stderr
    n = [s["n"] for s in json.loads((tmp_path / "b" / "prescription.json").read_text())["surfaces"]]
    assert n[:2] == [1.7, 1.7], n


def test_an_unsupported_surface_type_is_said_before_an_unknown_glass(tmp_path):
    """YuryStrelkov's F07g04: an unknown glass was refused first, and a user who gave it with --glass then met the
    file's real blocker, its 9 FZERNSAG surfaces. The surface type is said first."""
    from test_optics_window_ghosts import ZMX as WINDOW_ZMX

    text = WINDOW_ZMX.replace("  GLAS N-BK7 1 0 1.5168 64.17\n", "  GLAS MYGLASS\n")
    text = text.replace("SURF 2\n  TYPE STANDARD\n", "SURF 2\n  TYPE SZERNSAG\n", 1)
    assert "TYPE SZERNSAG" in text and "GLAS MYGLASS\n" in text
    lens = tmp_path / "lens.zmx"
    lens.write_text(text)
    r = _run("optics", "import", lens, "--out", tmp_path / "a")
    assert r.returncode == 2 and "surface 2: surface type SZERNSAG is not supported" in r.stderr, r.stderr
