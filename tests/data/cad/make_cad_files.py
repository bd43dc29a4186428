"""Generate the third-party-style CAD files in this folder (run once; the files are committed).

Three writers, none of them this project's own export path (geometry.io.export_assembly_step):

    python make_cad_files.py gmsh        # needs `pip install gmsh` (gmsh's own OpenCASCADE build)
    python make_cad_files.py ocp         # OCP's XDE writers directly (STEPCAFControl_Writer / IGESCAFControl_Writer)
    python make_cad_files.py cadquery    # CadQuery geometry (splines, ellipses, tori, fillets), cq.Assembly
    python make_cad_files.py fusion      # OCP's XDE writer, laid out as Fusion 360 writes an assembly

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
fusion_like_scope.step  (XDE, laid out as Fusion 360 exports: products "<component> v<k>", instances
    "<component> v<k>:<n>", bodies "Body<k>"; a small camera tube looking toward +z):
    top "guide v7" with
    "ar0130 v4:1" of product "ar0130 v4": the sensor (box 6 x 6 x 0.5 at z = 2);
    "Chip Mount v2:1" of "Chip Mount v2": an assembly whose own body (a ring z = 0..2) is an unnamed
        product beside its sub-component "lens v1:1" of "lens v1" (a disk r 12, z 40..44): the ring
        takes the component's name, "Chip Mount v2";
    "Tube v3:1" of "Tube v3": two bodies "Body2" (the wall r 20..22, z 0..80) and "Body3" (a flange ring)
        -> "Tube v3/Body2", "Tube v3/Body3";
    "Cap v1:1" of "Cap v1": two bodies "Body2" and "Body1" (rings at z = 80..82 and 82..84)
        -> "Cap v1/Body2", "Cap v1/Body1" (no clash with the tube's Body2);
    "Vane v1:1", "Vane v1:2" of one product "Vane v1" (rings at z = 20, 60) -> "Vane v1", "Vane v1_2".
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


def make_fusion_like():
    import cadquery as cq
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.STEPCAFControl import STEPCAFControl_Writer
    from OCP.STEPControl import STEPControl_AsIs
    from OCP.TCollection import TCollection_ExtendedString
    from OCP.TDataStd import TDataStd_Name
    from OCP.TDocStd import TDocStd_Document
    from OCP.TopLoc import TopLoc_Location
    from OCP.XCAFDoc import XCAFDoc_DocumentTool
    from OCP.gp import gp_Trsf, gp_Vec

    def ring(r_in, r_out, z0, dz):
        return cq.Workplane("XY").circle(r_out).circle(r_in).extrude(dz).translate((0, 0, z0)).val()

    def name(label, text):
        TDataStd_Name.Set_s(label, TCollection_ExtendedString(text))

    def moved(dz):
        t = gp_Trsf()
        t.SetTranslation(gp_Vec(0, 0, dz))
        return TopLoc_Location(t)

    doc = TDocStd_Document(TCollection_ExtendedString("XmlOcaf"))
    tool = XCAFDoc_DocumentTool.ShapeTool_s(doc.Main())
    top = tool.NewShape()
    name(top, "guide v7")

    def component(parent, shape_or_label, product, instance, location=None):
        label = shape_or_label if not hasattr(shape_or_label, "wrapped") else tool.AddShape(shape_or_label.wrapped,
                                                                                             False)
        if product is not None:
            name(label, product)
        comp = tool.AddComponent(parent, label, location or TopLoc_Location())
        if instance is not None:
            name(comp, instance)
        return label

    def bodies(shapes):
        """A product holding several bodies (named below, in the file's text)."""
        return tool.AddShape(cq.Compound.makeCompound(shapes).wrapped, False)

    sensor = cq.Workplane("XY").box(6, 6, 0.5).translate((0, 0, 2.25)).val()
    component(top, sensor, "ar0130 v4", "ar0130 v4:1")
    mount = tool.NewShape()
    name(mount, "Chip Mount v2")
    component(mount, ring(4, 19.9, 0, 2), None, None)  # the component's own body: an unnamed product
    lens = cq.Workplane("XY").circle(12).extrude(4).translate((0, 0, 40)).val()
    component(mount, lens, "lens v1", "lens v1:1")
    name(tool.AddComponent(top, mount, TopLoc_Location()), "Chip Mount v2:1")
    component(top, bodies([ring(20, 22, 0, 80), ring(22, 26, 0, 2)]), "Tube v3", "Tube v3:1")
    component(top, bodies([ring(14, 22, 80, 2), ring(20, 22, 82, 2)]), "Cap v1", "Cap v1:1")
    vane = tool.AddShape(ring(10, 19.9, 0, 1).wrapped, False)
    name(vane, "Vane v1")
    for k, dz in enumerate((20.0, 60.0), 1):
        comp = tool.AddComponent(top, vane, moved(dz))
        name(comp, f"Vane v1:{k}")
    tool.UpdateAssemblies()
    writer = STEPCAFControl_Writer()
    writer.SetNameMode(True)
    writer.Transfer(doc, STEPControl_AsIs)
    path = HERE / "fusion_like_scope.step"
    assert writer.Write(str(path)) == IFSelect_RetDone
    # Fusion names every body (MANIFOLD_SOLID_BREP('Body1', ...)); OCCT's writer leaves them empty: name them
    # in file order (sensor, mount ring, lens, tube x2, cap x2, vane)
    text = path.read_text()
    for body in ("Body1", "Body1", "Body1", "Body2", "Body3", "Body2", "Body1", "Body1"):
        assert "MANIFOLD_SOLID_BREP(''" in text
        text = text.replace("MANIFOLD_SOLID_BREP(''", f"MANIFOLD_SOLID_BREP('{body}'", 1)
    assert "MANIFOLD_SOLID_BREP(''" not in text
    path.write_text(text)


if __name__ == "__main__":
    {"gmsh": make_gmsh, "ocp": make_ocp, "cadquery": make_cadquery, "fusion": make_fusion_like}[sys.argv[1]]()
