"""Names as the CAD tool shows them (CONTRACTS 6.2): a solid is named by its product, its instance name is an
alias, both answer wherever a part is named; an unnamed component's body takes the component's name; the bodies
of a multi-body component are ``component/body``; every name is unique; `geometry check` shows both names.

Expected names are read from the STEP text: tests/data/cad/fusion_like_scope.step (written by
make_cad_files.py in Fusion 360's layout) and the Inventor file of tests/data/cad/THIRD_PARTY.md."""
from pathlib import Path

import pytest

from geometry.mesh import GeometryError

DATA = Path(__file__).resolve().parents[1] / "data" / "cad"
INVENTOR = DATA / "third_party" / "trj2_as1-in-203.stp"  # instances PLATE_1, BOLT_1... of products PLATE, BOLT...
FUSION = DATA / "fusion_like_scope.step"
ADAFRUIT = DATA / "third_party" / "adafruit_2831_photo_transistor.step"  # Fusion 360: components with two bodies each

FUSION_NAMES = {  # name -> aliases, by construction (make_cad_files.py make_fusion_like)
    "ar0130 v4": ("ar0130 v4:1",),
    "Chip Mount v2": ("Chip Mount v2:1",),  # the component's own body: an unnamed product ('SOLID', '=>[0:1:1:5]')
    "lens v1": ("lens v1:1",),
    "Tube v3/Body2": ("Tube v3:1/Body2", "Tube v3"),
    "Tube v3/Body3": ("Tube v3:1/Body3", "Tube v3"),
    "Cap v1/Body2": ("Cap v1:1/Body2", "Cap v1"),
    "Cap v1/Body1": ("Cap v1:1/Body1", "Cap v1"),
    "Vane v1": ("Vane v1:1",),
    "Vane v1_2": ("Vane v1:2",),
}


def _scene(tmp_path, body: str, extra: str = "") -> Path:
    toml = tmp_path / "scene.toml"
    toml.write_text(f'[[part]]\nname = "scope"\nmesh = "{FUSION}"\nsplit = "solids"\ntolerance_mm = 0.5\n'
                    f'material = "z307"\n{body}\n'
                    '[[source]]\ntype = "collimated_disk"\ncenter_mm = [0.0, 0.0, 100.0]\nnormal = [0.0, 0.0, -1.0]\n'
                    'direction = [0.0, 0.0, -1.0]\nradius_mm = 20.0\npower_w = 1.0\n' + extra)
    return toml


def test_fusion_layout_names_products_components_and_bodies():
    from geometry.cad import read_cad

    text = FUSION.read_text(encoding="latin-1")
    for what in ("PRODUCT('ar0130 v4'", "'ar0130 v4:1'", "PRODUCT('SOLID'", "MANIFOLD_SOLID_BREP('Body2'"):
        assert what in text  # what the file says
    solids = read_cad(FUSION)
    assert {s.name: s.aliases for s in solids} == FUSION_NAMES
    names = [s.name for s in solids] + [a for s in solids for a in s.aliases]
    assert not any(n.startswith("solid") for n in names)


def test_a_real_fusion_file_names_bodies_component_slash_body():
    from geometry.cad import read_cad

    text = ADAFRUIT.read_text(encoding="latin-1")
    for what in ("'Sensor:1'", "PRODUCT('Leads'", "MANIFOLD_SOLID_BREP('Base'", "MANIFOLD_SOLID_BREP('Emitter'"):
        assert what in text
    assert {s.name: s.aliases for s in read_cad(ADAFRUIT)} == {
        "Sensor/Base": ("Sensor:1/Base", "Sensor"), "Sensor/Sensor": ("Sensor:1/Sensor", "Sensor"),
        "Leads/Collector": ("Leads:1/Collector", "Leads"), "Leads/Emitter": ("Leads:1/Emitter", "Leads")}


def test_inventor_products_name_the_solids_and_instances_are_aliases():
    from geometry.cad import read_cad

    text = INVENTOR.read_text(encoding="latin-1")
    assert "'PLATE_1'" in text and "PRODUCT('PLATE'" in text.replace(" ", "")
    solids = read_cad(INVENTOR)
    by_name = {s.name: s for s in solids}
    assert by_name["PLATE"].aliases == ("PLATE_1",)
    assert by_name["BOLT_2"].aliases == ("BOLT_1",) and by_name["BOLT_2"].label == "BOLT"
    names = [s.name for s in solids]
    assert len(set(names)) == len(names)
    assert not set(names) & {a for s in solids for a in s.aliases}  # no alias is another solid's name


def test_override_by_product_or_instance_name(tmp_path):
    from geometry.io import load_cad_parts

    parts = load_cad_parts(INVENTOR, name="as1", tolerance_mm=0.5,
                           solids={"BOLT": {"role": "absorber"}, "PLATE_1": {"role": "detector"}})
    roles = {p.meta["solid"]: p.role for p in parts}
    assert roles["PLATE"] == "detector"
    bolts = [s for s in roles if s.startswith("BOLT")]
    assert len(bolts) == 6 and all(roles[s] == "absorber" for s in bolts)  # the product names all its instances
    assert roles["NUT"] == "surface"
    with pytest.raises(GeometryError, match=r"no solid named 'WASHER'.*PLATE \(PLATE_1\)"):
        load_cad_parts(INVENTOR, tolerance_mm=0.5, solids={"WASHER": {"role": "absorber"}})


@pytest.mark.parametrize("detector", ["scope/ar0130 v4", "scope/ar0130 v4:1"])
def test_analysis_detector_by_product_or_instance_name(tmp_path, detector):
    from straylight.analyses.scene_setup import scene_setup

    toml = _scene(tmp_path, '[part.solids."ar0130 v4:1"]\nrole = "detector"\n',
                  f'[analysis]\ndetector = "{detector}"\n')
    setup = scene_setup(toml)
    assert setup.detector == "scope/ar0130 v4"
    assert setup.scene.part("scope/ar0130 v4:1").name == "scope/ar0130 v4"
    assert scene_setup(toml, detector="scope/ar0130 v4:1").detector == "scope/ar0130 v4"  # --detector


def test_an_alias_of_several_parts_is_refused_naming_them(tmp_path):
    from straylight.scene import load_scene

    scene = load_scene(_scene(tmp_path, "")).scene
    assert scene.part("scope/Tube v3:1/Body3").name == "scope/Tube v3/Body3"
    with pytest.raises(GeometryError, match=r"'scope/Tube v3' names 2 parts \(scope/Tube v3/Body2, scope/Tube v3/Body3\)"):
        scene.part("scope/Tube v3")
    with pytest.raises(GeometryError, match=r"no part named 'scope/lens'.*scope/lens v1 \(scope/lens v1:1\)"):
        scene.part("scope/lens")


def test_thermal_temperature_by_instance_name(tmp_path):
    from straylight.api import thermal_scene
    from straylight.thermal.model import temperatures_with

    ts = thermal_scene(_scene(tmp_path, '[part.solids."ar0130 v4"]\nrole = "detector"\n'))
    temps = temperatures_with(ts, ["scope/lens v1:1=250"])
    assert temps[ts.part_index("scope/lens v1")] == 250.0 and ts.part_index("scope/lens v1:1") == ts.part_index("scope/lens v1")


def test_geometry_check_shows_both_names(tmp_path):
    import subprocess
    import sys

    toml = tmp_path / "scene.toml"
    toml.write_text(f'[[part]]\nname = "as1"\nmesh = "{INVENTOR}"\nsplit = "solids"\ntolerance_mm = 0.5\n'
                    f'material = "black"\n[part.solids."PLATE_1"]\nrole = "detector"\n')
    out = subprocess.run([sys.executable, "-c", "import sys; from straylight.cli.main import main; sys.exit(main())",
                          "geometry", "check", str(toml)],
                         capture_output=True, text=True, timeout=300)
    line = next(line for line in out.stdout.splitlines() if line.startswith("as1/PLATE "))
    assert "detector" in line and "(also: PLATE_1)" in line, out.stdout + out.stderr


def test_path_records_answer_to_instance_names(tmp_path):
    """Path queries (CONTRACTS 6.2): a path report asked for the detector by its instance name finds the
    records of the part named by its product."""
    from straylight.analyses.paths_report import path_report
    from straylight.analyses.scene_setup import scene_setup
    from straylight.trace import OutputOptions, TraceOptions, trace

    setup = scene_setup(_scene(tmp_path, '[part.solids."ar0130 v4"]\nrole = "detector"\n'))
    res = trace(setup.scene, [setup.beam.source(0.0)], 20_000, seed=3, materials=setup.materials,
                options=TraceOptions(output=OutputOptions(record_paths=True)))
    assert res.paths.resolve("scope/ar0130 v4:1") == "scope/ar0130 v4"
    assert res.detectors["scope/ar0130 v4:1"] is res.detectors["scope/ar0130 v4"]  # result tables too
    assert "scope/lens v1:1" in res.absorbed and list(res.detectors) == ["scope/ar0130 v4"]
    by_instance = path_report(res.paths, detector="scope/ar0130 v4:1")
    by_product = path_report(res.paths, detector="scope/ar0130 v4")
    assert by_instance.total_w == by_product.total_w > 0


@pytest.mark.parametrize("name", ["ar0130 v4", "ar0130 v4:1"])
def test_geometry_scene_takes_the_detector_by_either_name(tmp_path, name):
    from geometry.cad_scene import cad_scene_doc, detector_of

    doc, _ = cad_scene_doc(FUSION, tmp_path / "scope.toml", detector=name, tolerance_mm=0.5, name="scope")
    assert doc["part"][0]["solids"] == {"ar0130 v4": {"role": "detector"}}
    assert detector_of(doc) == "scope/ar0130 v4"
    with pytest.raises(GeometryError, match=r"no solid named 'ar0130'.*ar0130 v4 \(ar0130 v4:1\)"):
        cad_scene_doc(FUSION, tmp_path / "scope.toml", detector="ar0130", tolerance_mm=0.5)
