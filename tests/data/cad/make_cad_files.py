"""Generate the third-party-style CAD files in this folder (run once; the files are committed).

Three writers, none of them this project's own export path (geometry.io.export_assembly_step):

    python make_cad_files.py gmsh        # needs `pip install gmsh` (gmsh's own OpenCASCADE build)
    python make_cad_files.py ocp         # OCP's XDE writers directly (STEPCAFControl_Writer / IGESCAFControl_Writer)
    python make_cad_files.py cadquery    # CadQuery geometry (splines, ellipses, tori, fillets), cq.Assembly

Files and what the tests know about them (ground truth is set here, by construction):

gmsh_parts.step / gmsh_parts.iges  (gmsh 4.15 OCC kernel; gmsh writes no names: products are
    "Open CASCADE STEP translator 7.8 1.k", i.e. unnamed -> solid1..solid6)
    1 box 20 x 20 x 5 at z = 0..5, centred on the axis, with a filleted top (r = 2 -> cylinders)
    2 torus R = 15, r = 2 centred at z = 20 (axis z)
    3 elliptic cylinder (ellipse semi-axes 12 x 6) z = 30..33
    4 B-spline "bell": a closed B-spline curve in z = 40 swept up 4 mm (B-spline surface)
    5 sphere r = 5 at z = 55
    6 cone r 8 -> 3 over z = 65..75
ocp_bench_inch.step  (XDE, unit INCH), ocp_bench_m.step (unit METRE), ocp_bench.iges (IGES, unit INCH):
    assembly "bench" with instance names:
    "housing" (tube r 30..32, z 0..60, filleted rim: tori), "lens_1" (biconvex: two sphere caps),
    "vane" placed twice under product "vane" with no instance name (-> "vane", "vane_2"),
    "bspline_revolved" (B-spline profile revolved: surface of revolution), "offset_shell" (offset
    of a B-spline-faced loft: offset surfaces), one solid with no name at all (-> solid<k>), and
    "detector" (thin disk r 20, z -0.5..0). All lengths are written in mm in the model, the file
    stores them in inch / metre: the reader must give the same millimetres back.
cq_features.step  (CadQuery: cq.Assembly with names "spline_sweep", "ellipse_boss", "torus",
    "filleted_block", "detector")
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def make_gmsh():
    import gmsh

    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    occ = gmsh.model.occ
    box = occ.addBox(-10, -10, 0, 20, 20, 5)
    occ.synchronize()
    edges = []  # the four top edges of the box
    for dim, tag in gmsh.model.getEntities(1):
        x0, y0, z0, x1, y1, z1 = gmsh.model.getBoundingBox(dim, tag)
        if min(z0, z1) > 4.99:
            edges.append(tag)
    occ.fillet([box], edges, [2.0])
    occ.addTorus(0, 0, 20, 15, 2)
    ellipse = occ.addEllipse(0, 0, 30, 12, 6)
    loop = occ.addCurveLoop([ellipse])
    disk = occ.addPlaneSurface([loop])
    occ.extrude([(2, disk)], 0, 0, 3)
    pts = [occ.addPoint(10 * math.cos(a) * (1 + 0.3 * math.cos(3 * a)), 10 * math.sin(a), 40)
           for a in [2 * math.pi * k / 9 for k in range(9)]]
    spline = occ.addBSpline(pts + [pts[0]])
    loop = occ.addCurveLoop([spline])
    bell = occ.addPlaneSurface([loop])
    occ.extrude([(2, bell)], 0, 0, 4)
    occ.addSphere(0, 0, 55, 5)
    occ.addCone(0, 0, 65, 0, 0, 10, 8, 3)
    occ.synchronize()
    assert len(gmsh.model.getEntities(3)) == 6, gmsh.model.getEntities(3)
    gmsh.write(str(HERE / "gmsh_parts.step"))
    gmsh.write(str(HERE / "gmsh_parts.iges"))
    gmsh.finalize()


def _xde_document():
    import cadquery as cq
    from OCP.BRepOffsetAPI import BRepOffsetAPI_MakeOffsetShape
    from OCP.BRepOffset import BRepOffset_Skin
    from OCP.GeomAbs import GeomAbs_Arc
    from OCP.gp import gp_Trsf, gp_Vec
    from OCP.TCollection import TCollection_ExtendedString
    from OCP.TDataStd import TDataStd_Name
    from OCP.TDocStd import TDocStd_Document
    from OCP.TopLoc import TopLoc_Location
    from OCP.XCAFDoc import XCAFDoc_DocumentTool

    housing = (cq.Workplane("XY").circle(32).circle(30).extrude(60).faces(">Z").edges().fillet(0.8).val())
    lens = (cq.Workplane("XY").sphere(40).translate((0, 0, 70 - 40 + 3))
            .intersect(cq.Workplane("XY").sphere(40).translate((0, 0, 70 + 40 - 3)))
            .intersect(cq.Workplane("XY").circle(14).extrude(20).translate((0, 0, 60))).val())
    vane = cq.Workplane("XY").circle(29.9).circle(20).extrude(1).val()
    profile = cq.Workplane("XZ").spline([(5, 80), (9, 83), (7, 87), (10, 90)], includeCurrent=False) \
        .lineTo(0, 90).lineTo(0, 80).close()
    revolved = profile.revolve(360, (0, 0, 0), (0, 1, 0)).val()
    loft = (cq.Workplane("XY").workplane(offset=100).spline([(6, 0), (0, 5), (-6, 0), (0, -4)], periodic=True)
            .close().workplane(offset=6).circle(4).loft().val())
    maker = BRepOffsetAPI_MakeOffsetShape()
    maker.PerformByJoin(loft.wrapped, 0.5, 1e-4, BRepOffset_Skin, False, False, GeomAbs_Arc)
    offset = cq.Shape.cast(maker.Shape())
    plain = cq.Workplane("XY").box(6, 6, 6).translate((40, 0, 30)).val()
    detector = cq.Workplane("XY").circle(20).extrude(0.5).translate((0, 0, -0.5)).val()

    doc = TDocStd_Document(TCollection_ExtendedString("XmlOcaf"))
    tool = XCAFDoc_DocumentTool.ShapeTool_s(doc.Main())
    top = tool.NewShape()
    TDataStd_Name.Set_s(top, TCollection_ExtendedString("bench"))

    def add(shape, product_name, location=None, instance_name=None):
        label = tool.AddShape(shape.wrapped, False)
        if product_name is not None:
            TDataStd_Name.Set_s(label, TCollection_ExtendedString(product_name))
        component = tool.AddComponent(top, label, location or TopLoc_Location())
        if instance_name is not None:
            TDataStd_Name.Set_s(component, TCollection_ExtendedString(instance_name))
        return label

    def moved(dz):
        t = gp_Trsf()
        t.SetTranslation(gp_Vec(0, 0, dz))
        return TopLoc_Location(t)

    add(housing, "housing_product", instance_name="housing")
    add(lens, "lens_product", instance_name="lens_1")
    vane_label = tool.AddShape(vane.wrapped, False)
    TDataStd_Name.Set_s(vane_label, TCollection_ExtendedString("vane"))
    for dz in (20.0, 40.0):  # one product, two placements, no instance names
        tool.AddComponent(top, vane_label, moved(dz))
    add(revolved, "bspline_revolved")
    add(offset, "offset_shell")
    add(plain, None)
    add(detector, "detector")
    tool.UpdateAssemblies()
    return doc


def make_ocp():
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.IGESCAFControl import IGESCAFControl_Writer
    from OCP.Interface import Interface_Static
    from OCP.STEPCAFControl import STEPCAFControl_Writer
    from OCP.STEPControl import STEPControl_AsIs

    doc = _xde_document()
    for unit, name in (("INCH", "ocp_bench_inch.step"), ("M", "ocp_bench_m.step")):
        Interface_Static.SetCVal_s("write.step.unit", unit)
        writer = STEPCAFControl_Writer()
        writer.SetNameMode(True)
        writer.Transfer(doc, STEPControl_AsIs)
        assert writer.Write(str(HERE / name)) == IFSelect_RetDone
    Interface_Static.SetCVal_s("write.step.unit", "MM")
    Interface_Static.SetCVal_s("write.iges.unit", "IN")
    Interface_Static.SetIVal_s("write.iges.brep.mode", 1)  # solids as MSBO (B-rep), as CAD tools do
    writer = IGESCAFControl_Writer()
    writer.SetNameMode(True)
    writer.Transfer(doc)
    assert writer.Write(str(HERE / "ocp_bench.iges"))


def make_cadquery():
    import cadquery as cq

    path = cq.Workplane("XZ").spline([(0, 0), (5, 10), (0, 20), (-5, 30)], includeCurrent=False)
    sweep = cq.Workplane("XY").circle(2).sweep(path).val()
    ellipse = cq.Workplane("XY").workplane(offset=40).ellipse(10, 5).extrude(4).edges(">Z").fillet(1).val()
    torus = cq.Solid.makeTorus(12, 2.5).translate(cq.Vector(0, 0, 55))
    block = cq.Workplane("XY").box(20, 14, 6).translate((0, 0, 70)).edges("|Z").fillet(3).edges(">Z").fillet(1).val()
    detector = cq.Workplane("XY").circle(15).extrude(0.5).translate((0, 0, -0.5)).val()
    assembly = cq.Assembly(name="cq_features")
    for name, shape in (("spline_sweep", sweep), ("ellipse_boss", ellipse), ("torus", torus),
                        ("filleted_block", block), ("detector", detector)):
        assembly.add(shape, name=name)
    assembly.export(str(HERE / "cq_features.step"), exportType="STEP")


if __name__ == "__main__":
    {"gmsh": make_gmsh, "ocp": make_ocp, "cadquery": make_cadquery}[sys.argv[1]]()
