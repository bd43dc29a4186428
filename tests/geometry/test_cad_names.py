"""Names as the user knows them (CONTRACTS 6.2): a solid answers to its instance name and its product name,
and a multi-body part's solids take their body names; `geometry check` shows both names.

Expected names are read from the STEP text of the third-party files (tests/data/cad/THIRD_PARTY.md)."""
from pathlib import Path

import pytest

from geometry.mesh import GeometryError

CORPUS = Path(__file__).resolve().parents[1] / "data" / "cad" / "third_party"
INVENTOR = CORPUS / "trj2_as1-in-203.stp"  # instances PLATE_1, BOLT_1... of products PLATE, BOLT...
FUSION = CORPUS / "PiFinder_DIY_v2.step"  # one part with bodies pi_mount, shroud, bezel...


def test_instance_and_product_names_are_read():
    from geometry.cad import read_cad

    text = INVENTOR.read_text(encoding="latin-1")
    assert "'PLATE_1'" in text and "PRODUCT('PLATE'" in text.replace(" ", "")  # what the file says
    solids = {s.name: s for s in read_cad(INVENTOR)}
    assert solids["PLATE_1"].aliases == ("PLATE",)
    assert solids["BOLT_1"].aliases == ("BOLT",)


def test_bodies_of_one_fusion_part_take_their_body_names():
    from geometry.cad import read_cad

    text = FUSION.read_text(encoding="latin-1")
    bodies = {"pi_mount", "flat_adapter", "shroud", "bezel", "flat_shroud"}
    assert all(f"MANIFOLD_SOLID_BREP('{b}'" in text for b in bodies)
    solids = read_cad(FUSION)
    assert {s.name for s in solids} == bodies
    assert all(s.aliases == ("PiFinder_DIY_v2 v110",) for s in solids)


def test_override_by_product_name_applies_to_its_instances(tmp_path):
    from geometry.io import load_cad_parts

    parts = load_cad_parts(INVENTOR, name="as1", tolerance_mm=0.5,
                           solids={"BOLT": {"role": "absorber"}, "PLATE_1": {"role": "detector"}})
    roles = {p.meta["solid"]: p.role for p in parts}
    assert roles["PLATE_1"] == "detector"
    bolts = [s for s in roles if s.startswith("BOLT_1")]
    assert len(bolts) >= 2 and all(roles[s] == "absorber" for s in bolts)
    assert roles["NUT_1"] == "surface"
    with pytest.raises(GeometryError, match=r"no solid named 'WASHER'.*PLATE_1 \(PLATE\)"):
        load_cad_parts(INVENTOR, tolerance_mm=0.5, solids={"WASHER": {"role": "absorber"}})


def test_geometry_check_shows_both_names(tmp_path):
    import subprocess
    import sys

    toml = tmp_path / "scene.toml"
    toml.write_text(f'[[part]]\nname = "as1"\nmesh = "{INVENTOR}"\nsplit = "solids"\ntolerance_mm = 0.5\n'
                    f'material = "black"\n[part.solids."PLATE"]\nrole = "detector"\n')
    out = subprocess.run([sys.executable, "-c", "import sys; from straylight.cli.main import main; sys.exit(main())",
                          "geometry", "check", str(toml)],
                         capture_output=True, text=True, timeout=300)
    line = next(line for line in out.stdout.splitlines() if line.startswith("as1/PLATE_1"))
    assert "detector" in line and "(also: PLATE)" in line, out.stdout + out.stderr
