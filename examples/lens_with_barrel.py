"""End to end: a designer's lens file + a CadQuery barrel with vanes -> PST and stray-light paths.

    python examples/lens_with_barrel.py OUT_DIR
    straylight pst OUT_DIR/scene.toml --angles-deg 20 30 45 --rays 20000 --out OUT_DIR/pst
    straylight paths OUT_DIR/scene.toml --angle-deg 30 --rays 20000 --out OUT_DIR/paths

1. ``straylight optics import`` turns the double Gauss (tests/data/lenses/ray-optics/ag_dblgauss.seq, f = 100 mm,
   f/2, 14 deg half field) into OUT_DIR/lens/scene.toml: exact lens surfaces, black edges and stop, the
   ``image`` detector and the ``pupil`` source (frame: first lens vertex at the origin, light toward +z).
2. A barrel is built in CadQuery in the same frame (a tube around the lenses with a sunshade of two vanes in
   front of the first lens, cleared for the 14 deg field) and exported to OUT_DIR/barrel.step.
3. OUT_DIR/scene.toml is the lens scene plus one ``[[part]]`` for the STEP barrel (split into its solids), with
   the source moved to the barrel's mouth so that off-axis light enters the sunshade the way it does outdoors.
"""
import math
import subprocess
import sys
from pathlib import Path

import cadquery as cq

ROOT = Path(__file__).resolve().parents[1]
LENS = ROOT / "tests" / "data" / "lenses" / "ray-optics" / "ag_dblgauss.seq"
BORE_MM = 40.0          # barrel inner radius (the largest lens clear aperture is 29.6 mm)
FRONT_MM = -30.0        # barrel mouth (z of the sunshade's front)
BACK_MM = 135.0         # behind the last lens, short of the image plane (z = 139.5 mm)
FIELD_DEG = 14.0


def barrel():
    wall = cq.Workplane("XY").workplane(offset=FRONT_MM).circle(BORE_MM + 2.0).circle(BORE_MM) \
        .extrude(BACK_MM - FRONT_MM)
    asm = cq.Assembly(name="barrel")
    asm.add(wall, name="wall")
    for k, z in enumerate((-25.0, -12.0), start=1):
        hole = 29.6 + (0.0 - z) * math.tan(math.radians(FIELD_DEG)) + 1.0  # clears the 14 deg beam
        vane = cq.Workplane("XY").workplane(offset=z - 0.5).circle(BORE_MM).circle(hole).extrude(1.0)
        asm.add(vane, name=f"vane_{k}")
    return asm


def main(out):
    out = Path(out)
    subprocess.run([sys.executable, "-m", "straylight.cli.main", "optics", "import", str(LENS), "--out",
                    str(out / "lens")], check=True)
    barrel().save(str(out / "barrel.step"))
    text = (out / "lens" / "scene.toml").read_text()
    z_src = FRONT_MM - 1.0
    head, _, src = text.partition("[[source]]")
    src = "\n".join(f"center_mm = [0.0, 0.0, {z_src}]" if ln.startswith("center_mm") else
                    f"radius_mm = {BORE_MM + 2.0}" if ln.startswith("radius_mm") else ln for ln in src.splitlines())
    barrel_part = ('[[part]]\nname = "barrel"\nmesh = "barrel.step"\nsplit = "solids"\n'
                   'material = "z302_sample_b"\nrole = "surface"\n\n')
    (out / "scene.toml").write_text(head + barrel_part + "[[source]]" + src + "\n")
    print(f"wrote {out / 'scene.toml'} (lens + barrel.step)")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "lens_with_barrel")
