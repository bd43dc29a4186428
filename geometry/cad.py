"""Reading CAD exchange files (STEP, IGES) from any CAD tool, with their assembly names and units.

:func:`read_cad` reads a file through OpenCascade's XDE readers (``STEPCAFControl_Reader`` /
``IGESCAFControl_Reader``), which keep the assembly structure and the names the CAD tool gave
to products and instances, and returns one :class:`CadSolid` per solid in file order, placed in
the assembly (instance locations applied) and in **millimetres** whatever unit the file uses
(OpenCascade converts to its session unit, mm).

Names (CONTRACTS §6.2): a solid takes its product's name (the component, Fusion's ``lens v1``) and also
answers to its instance's name (``CadSolid.aliases``: ``lens v1:1``); a component written without a name
takes the name of the nearest named component above it; the bodies of a multi-body component are
``component/body`` (of a one-part file, their body names); a solid without any name (or with only a
writer's placeholder, see ``_PLACEHOLDERS``) is ``solid<k>`` (k from 1, in file order); repeated names
get ``_2``, ``_3``; no alias is another solid's name. Surface models (IGES files usually hold faces,
not solids) are sewn: closed shells become solids, open ones stay sheets.

Every failure is a one-line :class:`geometry.mesh.GeometryError` naming the file.
"""
from __future__ import annotations

import re
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from geometry.mesh import GeometryError

STEP_SUFFIXES = (".step", ".stp")
IGES_SUFFIXES = (".iges", ".igs")
CAD_SUFFIXES = STEP_SUFFIXES + IGES_SUFFIXES


@dataclass(frozen=True, eq=False)
class CadSolid:
    """One solid (or a free sheet) of a CAD file: its unique name, the OCP shape (placed, mm), and
    ``kind`` "solid" or "sheet"; ``label`` is the name as written in the file (None if unnamed)."""

    name: str
    shape: object
    kind: str
    label: str | None
    aliases: tuple = ()  # the other names the file gives it (its product's name when named after its instance)


_PLACEHOLDERS = re.compile(r"^(=>\[[0-9:]*\]|[0-9]+|Open CASCADE STEP translator .*|NAUO[0-9]*|"
                           r"COMPOUND|COMPSOLID|SOLID|SHELL|FACE)$")
"""Names that writers put where the user gave none: OpenCascade's label paths ("=>[0:1:1:8]"),
bare entity ids ("1", "NAUO12": the reader falls back to the id when an instance has no name),
OpenCascade's default product name ("Open CASCADE STEP translator 7.8 1.1", gmsh's files) and the
shape type its IGES reader gives an unnamed entity ("COMPOUND")."""
SEWING_TOLERANCE_MM = 1e-3


def _label_name(label) -> str | None:
    """The label's name, or None if it has none or only a writer's placeholder."""
    from OCP.TDataStd import TDataStd_Name

    if not label.IsAttribute(TDataStd_Name.GetID_s()):
        return None
    attr = TDataStd_Name()
    if label.FindAttribute(TDataStd_Name.GetID_s(), attr):
        text = attr.Get().ToExtString().strip()
        return None if not text or _PLACEHOLDERS.match(text) else text
    return None


@contextmanager
def _quiet_opencascade():
    """OpenCascade's readers print statistics to stdout ("Total number of loaded entities"); mute them."""
    from OCP.Message import Message, Message_PrinterOStream

    messenger = Message.DefaultMessenger_s()
    printers = [messenger.Printers().Value(i) for i in range(1, messenger.Printers().Length() + 1)]
    messenger.RemovePrinters(Message_PrinterOStream.get_type_descriptor_s())
    try:
        yield
    finally:
        for printer in printers:
            if printer.IsKind(Message_PrinterOStream.get_type_descriptor_s()):
                messenger.AddPrinter(printer)


def _read_document(path: Path):
    """XDE document of a STEP/IGES file (names, colours, assembly structure kept)."""
    from OCP.TCollection import TCollection_ExtendedString
    from OCP.TDocStd import TDocStd_Document

    suffix = path.suffix.lower()
    if suffix in STEP_SUFFIXES:
        from OCP.STEPCAFControl import STEPCAFControl_Reader as Reader
        kind = "STEP"
    elif suffix in IGES_SUFFIXES:
        from OCP.IGESCAFControl import IGESCAFControl_Reader as Reader
        kind = "IGES"
    else:
        raise GeometryError(f"{path}: not a CAD exchange file (expected {', '.join(CAD_SUFFIXES)})")
    if not path.is_file():
        raise GeometryError(f"{path}: file not found")
    from OCP.XCAFApp import XCAFApp_Application

    app = XCAFApp_Application.GetApplication_s()
    doc = TDocStd_Document(TCollection_ExtendedString("MDTV-XCAF"))
    app.InitDocument(doc)
    reader = Reader()
    reader.SetNameMode(True)
    if kind == "STEP":  # keep the names of a part's bodies (MANIFOLD_SOLID_BREP) as sub-shape labels
        from OCP.Interface import Interface_Static

        Interface_Static.SetIVal_s("read.stepcaf.subshapes.name", 1)
    with _quiet_opencascade():
        return _transfer(reader, doc, path, kind)


def _transfer(reader, doc, path: Path, kind: str):
    from OCP.IFSelect import IFSelect_RetDone

    try:
        status = reader.ReadFile(str(path))
    except Exception as exc:  # noqa: BLE001 - OCC raises bare Standard_Failure; name the file
        raise GeometryError(f"{path}: cannot read {kind} file: {exc}") from None
    if status != IFSelect_RetDone:
        raise GeometryError(f"{path}: not a readable {kind} file (OpenCascade reader status {int(status)}: "
                            f"syntax error, truncated file or wrong format)")
    try:
        ok = reader.Transfer(doc)
    except Exception as exc:  # noqa: BLE001
        raise GeometryError(f"{path}: cannot translate the {kind} entities to shapes: {exc}") from None
    if not ok:
        raise GeometryError(f"{path}: the {kind} file holds no shape that OpenCascade can translate")
    return doc, reader


def _explore(shape, kind):
    from OCP.TopExp import TopExp_Explorer

    out = []
    explorer = TopExp_Explorer(shape, kind)
    while explorer.More():
        out.append(explorer.Current())
        explorer.Next()
    return out


def _sub_solids(shape):
    """[(shape, kind)]: the solids of ``shape`` in order; a surface model (faces only, as IGES files and
    some STEP files hold) is first sewn (``BRepBuilderAPI_Sewing``): every closed shell becomes a solid
    (outward oriented), open shells and loose faces stay sheets."""
    from OCP.BRep import BRep_Builder, BRep_Tool
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeSolid, BRepBuilderAPI_Sewing
    from OCP.BRepLib import BRepLib
    from OCP.TopAbs import TopAbs_FACE, TopAbs_SHELL, TopAbs_SOLID
    from OCP.TopoDS import TopoDS, TopoDS_Shell

    solids = _explore(shape, TopAbs_SOLID)
    if solids:
        return [(s, "solid") for s in solids]
    faces = _explore(shape, TopAbs_FACE)
    if not faces:
        return []
    sewing = BRepBuilderAPI_Sewing(SEWING_TOLERANCE_MM)
    for face in faces:
        sewing.Add(face)
    sewing.Perform()
    sewn = sewing.SewedShape()
    shells = [TopoDS.Shell_s(shell) for shell in _explore(sewn, TopAbs_SHELL)]
    in_shells = {f.__hash__() for shell in shells for f in _explore(shell, TopAbs_FACE)}
    builder = BRep_Builder()
    for face in _explore(sewn, TopAbs_FACE):  # a loose face may be closed by itself (a torus, a sphere)
        if face.__hash__() not in in_shells:
            shell = TopoDS_Shell()
            builder.MakeShell(shell)
            builder.Add(shell, face)
            shells.append(shell)
    found = []
    for shell in shells:
        if BRep_Tool.IsClosed_s(shell):
            solid = BRepBuilderAPI_MakeSolid(shell).Solid()
            BRepLib.OrientClosedSolid_s(solid)
            found.append((solid, "solid"))
        else:
            found.append((shell, "sheet"))
    return found


def _walk(shape_tool, label, location, name, out, aliases=(), inherited=None):
    """Depth-first over an XDE label: assemblies recurse into their components (locations composed),
    simple shapes contribute their solids as ``(shape, kind, name, aliases, label)``.

    A component is named by its product (CONTRACTS 6.2), its instance name (Fusion's ``lens:1``) an
    alias; a component without either name takes the name of the nearest named component above it
    (``inherited``: CAD tools write a component's own bodies as an unnamed product next to its
    sub-components); the bodies of a multi-body part are ``<component>/<body>``."""
    from OCP.TDF import TDF_Label, TDF_LabelSequence
    from OCP.XCAFDoc import XCAFDoc_ShapeTool

    if XCAFDoc_ShapeTool.IsAssembly_s(label):
        components = TDF_LabelSequence()
        XCAFDoc_ShapeTool.GetComponents_s(label, components, False)
        for i in range(1, components.Length() + 1):
            component = components.Value(i)
            referred = TDF_Label()
            XCAFDoc_ShapeTool.GetReferredShape_s(component, referred)
            child_location = location.Multiplied(XCAFDoc_ShapeTool.GetLocation_s(component))
            product, instance = _label_name(referred), _label_name(component)
            child_name = product or instance
            child_aliases = (instance,) if instance and instance != child_name else ()
            if child_name is None:
                child_name, child_aliases = (name, aliases) if name else (inherited, ())
            _walk(shape_tool, referred, child_location, child_name, out, child_aliases,
                  child_name or name or inherited)
        return
    shape = XCAFDoc_ShapeTool.GetShape_s(label)
    if shape.IsNull():
        return
    root = name is None and inherited is None  # the file's own top shape, not a component of an assembly
    if name is None:
        name = _label_name(label) or inherited
    subs = _sub_solids(shape)
    for sub, kind in subs:
        body = _body_name(shape_tool, label, sub) if len(subs) > 1 else None
        if body and name and root and body != name:  # a one-part file's bodies: their own names
            out.append((sub.Moved(location), kind, body, (f"{name}/{body}", name)))
        elif body and name:  # a named body of a multi-body component: component/body (Sensor/Sensor too)
            out.append((sub.Moved(location), kind, f"{name}/{body}",
                        tuple(f"{a}/{body}" for a in aliases if a) + (name,)))
        elif body and not name:
            out.append((sub.Moved(location), kind, body, ()))
        else:
            out.append((sub.Moved(location), kind, name, tuple(a for a in aliases if a)))


def _body_name(shape_tool, label, sub) -> str | None:
    """The name the file gives one solid of a part (STEP ``MANIFOLD_SOLID_BREP('pi_mount', ...)``), if the
    reader kept it as a sub-shape label."""
    from OCP.TDF import TDF_Label

    try:
        sublabel = TDF_Label()
        if shape_tool.FindSubShape(label, sub, sublabel):
            return _label_name(sublabel)
    except Exception:  # noqa: BLE001 - a missing body name is not an error
        return None
    return None


def unique_names(names) -> list[str]:
    """None -> ``solid<k>`` (k = position from 1); repeated names get ``_2``, ``_3`` (first keeps its name)."""
    out, seen = [], {}
    raw = [n if n else f"solid{k}" for k, n in enumerate(names, start=1)]
    taken = set(raw)
    for n in raw:
        if n not in seen:
            seen[n] = 1
            out.append(n)
            continue
        k = seen[n]
        while True:
            k += 1
            candidate = f"{n}_{k}"
            if candidate not in taken:
                break
        seen[n] = k
        taken.add(candidate)
        out.append(candidate)
    return out


def read_cad(path) -> list[CadSolid]:
    """Every solid of a STEP or IGES file, placed, in mm, with unique names (see the module docstring)."""
    from OCP.TDF import TDF_LabelSequence
    from OCP.TopLoc import TopLoc_Location
    from OCP.XCAFDoc import XCAFDoc_DocumentTool

    path = Path(path)
    doc, reader = _read_document(path)  # the reader stays referenced until the walk is done
    shape_tool = XCAFDoc_DocumentTool.ShapeTool_s(doc.Main())
    free = TDF_LabelSequence()
    shape_tool.GetFreeShapes(free)
    found: list[tuple] = []  # (shape, kind, name, aliases, label) per solid
    for i in range(1, free.Length() + 1):
        label = free.Value(i)
        _walk(shape_tool, label, TopLoc_Location(), None, found)
    del reader
    if not found:
        raise GeometryError(f"{path}: the file holds no solid, shell or face")
    return named_solids(found)


def named_solids(found) -> list[CadSolid]:
    """:class:`CadSolid` s of ``[(shape, kind, name, aliases)]`` with unique names (``unique_names``) and
    aliases: the other names the file gives (instance names, a multi-body part's component), none equal to
    another solid's name. ``label`` keeps the name before suffixes (``BOLT`` for ``BOLT_2``)."""
    names = unique_names([name for _, _, name, _ in found])
    taken = set(names)
    out = []
    for n, (shape, kind, label, aliases) in zip(names, found):
        kept = []
        for a in aliases:
            if a and a != n and a not in taken and a not in kept:
                kept.append(a)
        out.append(CadSolid(n, shape, kind, label, tuple(kept)))
    return out


def compound_of(shapes):
    """One OCP compound holding ``shapes``."""
    from OCP.BRep import BRep_Builder
    from OCP.TopoDS import TopoDS_Compound

    compound = TopoDS_Compound()
    builder = BRep_Builder()
    builder.MakeCompound(compound)
    for shape in shapes:
        builder.Add(compound, shape)
    return compound
