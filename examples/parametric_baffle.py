"""A parametric baffle tube in plain CadQuery, for ``straylight study --model``.

    straylight study --model examples/parametric_baffle.py:build \\
        --sweep-parameter vane_count --sweep-values 3 5 7 --rays 20000 --out baffle_report

``build(**params)`` returns named CadQuery parts; ``SCENE`` says what CAD does not: roles,
materials, the source and the entrance (docs/study.md, "Parametric designs"). Any keyword of
``build`` can be swept (vane_count, vane_hole_radius_mm, length_mm, ...).
"""
import cadquery as cq

RADIUS_MM = 50.0
WALL_MM = 1.0
LENGTH_MM = 300.0
DETECTOR_RADIUS_MM = 30.0


def build(vane_count: int = 5, vane_hole_radius_mm: float = 35.0, vane_thickness_mm: float = 1.0,
          length_mm: float = LENGTH_MM):
    """Tube wall, ``vane_count`` evenly spaced annular vanes, an end plate and a detector disk at z = 0."""
    parts = {
        "wall": cq.Workplane("XY").circle(RADIUS_MM + WALL_MM).circle(RADIUS_MM).extrude(length_mm),
        "end_plate": cq.Workplane("XY").workplane(offset=-WALL_MM)
        .circle(RADIUS_MM + WALL_MM).circle(DETECTOR_RADIUS_MM).extrude(WALL_MM),
        # a sheet: the detector's sensitive face (a thin solid from CAD works as well)
        "detector": cq.Face.makeFromWires(cq.Wire.makeCircle(DETECTOR_RADIUS_MM, cq.Vector(0, 0, 0),
                                                              cq.Vector(0, 0, 1))),
    }
    for k in range(int(vane_count)):
        z = length_mm * (k + 1) / (int(vane_count) + 1)
        parts[f"vane_{k + 1}"] = (cq.Workplane("XY").workplane(offset=z - vane_thickness_mm / 2)
                                  .circle(RADIUS_MM).circle(vane_hole_radius_mm).extrude(vane_thickness_mm))
    return parts


SCENE = {
    "parts": {"detector": {"role": "detector"},
              "*": {"role": "surface", "material": "z302_sample_b"}},
    "source": [{"type": "collimated_disk", "center_mm": [0.0, 0.0, LENGTH_MM + 10.0], "normal": [0.0, 0.0, -1.0],
                "direction": [0.0, 0.0, -1.0], "radius_mm": RADIUS_MM + WALL_MM}],
    "analysis": {"detector": "detector",
                 "entrance": {"center_mm": [0.0, 0.0, LENGTH_MM], "normal": [0.0, 0.0, 1.0], "radius_mm": RADIUS_MM}},
    "tolerance_mm": 0.1,
}
