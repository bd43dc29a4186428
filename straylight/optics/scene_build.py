"""A :class:`~straylight.optics.reader.Prescription` as a scene (docs/optics.md): one exact analytic part per
optical surface, black lens edges and stop, the ``image`` detector and the ``pupil`` source.

Sag convention (docs/reference/scene.md, analytic surfaces): h(rho) = c rho^2 / (1 + sqrt(1 - (1 + k) c^2
rho^2)) + sum A_(2i+4) rho^(2i+4) (+ sum a_p rho^p, ``power_terms``) along the part's ``axis``; the lens
file's sag is along the surface's own +z, so a part whose ``axis`` is the opposite direction gets -R, -A and -a.
"""
from __future__ import annotations

import math
import re
from typing import Any

import numpy as np

from straylight.optics import aperture
from straylight.optics.aluminium import aluminium_nk
from straylight.optics.reader import require_optical_surface
from straylight.optics.sag import sag_mm

EDGE_MATERIAL = "z302_sample_b"
#: the stop ring's distance in front of the stop surface's part (twice the default mesh tolerance, 0.01 mm: a
#: curved surface's facets lie up to it in front of the exact surface)
STOP_CLEARANCE_MM = 0.02


def _v(a) -> list:
    return [round(float(x), 10) + 0.0 for x in a]


def _surface_table(s, axis, outer, inner=0.0) -> dict:
    """The 6.1 ``surface`` table of ``s`` seen along ``axis`` (sign flipped when axis opposes its own z)."""
    sign = 1.0 if float(np.dot(axis, s.local_z)) > 0 else -1.0
    d: dict[str, Any] = {"vertex_mm": _v(s.vertex_mm), "axis": _v(axis)}
    if s.type == "plane" and aperture.is_off_axis(s):  # an off-axis flat segment: a conic with c = 1e-18 /mm
        d = {"type": "conic", **d, "radius_mm": 1e18, "conic": 0.0}
    elif s.type == "plane":
        d = {"type": "plane", **d}
    elif s.type == "asphere":  # a flat base: c = 1e-18 /mm, the plane to 1e-12 mm over a metre
        d = {"type": "asphere", **d, "radius_mm": sign * (s.radius_mm if s.radius_mm else 1e18), "conic": s.conic,
             "coefficients": [sign * a for a in s.coefficients]}
        if s.power_terms:  # odd or r^2 terms: the scene's power_terms, flipped with the rest
            d["power_terms"] = [[int(p), sign * a] for p, a in s.power_terms]
    else:
        d = {"type": "conic", **d, "radius_mm": sign * s.radius_mm, "conic": s.conic}
    d["outer_radius_mm"] = float(outer)
    if inner > 0:
        d["inner_radius_mm"] = float(inner)
    d.update(aperture.scene_keys(s))
    return d


def _same_geometry(a, b) -> bool:
    if np.linalg.norm(a.vertex_mm - b.vertex_mm) > 1e-6 or abs(abs(np.dot(a.local_z, b.local_z)) - 1) > 1e-9:
        return False
    if (a.radius_mm is None) != (b.radius_mm is None) or a.type != b.type:
        return False
    if a.radius_mm is not None and abs(a.radius_mm - b.radius_mm) > 1e-9 * abs(a.radius_mm):
        return False
    if len(a.coefficients) != len(b.coefficients) or dict(a.power_terms) != dict(b.power_terms):
        return False
    return abs(a.conic - b.conic) < 1e-12 and np.allclose(a.coefficients, b.coefficients)


def _same_media(a, b) -> bool:
    """Surfaces between the same two media, in either direction."""
    return abs(min(a.n, a.n_before) - min(b.n, b.n_before)) < 1e-9 and abs(max(a.n, a.n_before)
                                                                         - max(b.n, b.n_before)) < 1e-9


def _leave_centre(placed_surface, radius_mm: float, optical: list) -> None:
    """A surface met again between other media, within a smaller aperture (a catadioptric's rear group cemented in
    its primary's centre: the Reflex-Nikkor 500 mm's last element against the Mangin's front) is its own part over
    that centre: the part placed first keeps the annulus outside it (a hole, as the sequential check sees it)."""
    part = next(pt for q, pt in optical if q is placed_surface)
    inner = max(float(part["surface"].get("inner_radius_mm", 0.0)), radius_mm)
    part["surface"]["inner_radius_mm"] = inner
    placed_surface.inner_kind, placed_surface.inner_radius_mm = placed_surface.inner_kind or "hole", inner


def _share_hole(p, surface) -> None:
    """The same glass surface met again (the light's way back through it) gets ``surface``'s hole."""
    for q in p.surfaces:
        if q is not surface and not q.mirror and _same_geometry(q, surface) and _same_media(q, surface):
            q.inner_kind, q.inner_radius_mm = surface.inner_kind, surface.inner_radius_mm


def _in_contact(p) -> dict:
    """{index of the second surface: index of the first} for two glasses in contact: a surface from glass into air
    with no thickness after it, then a surface of the same shape from air into glass (OpticsDatabase's Samyang 50 mm
    F1.4 and 20 more of its lenses write elements that touch so). The air between has no thickness: rays refract
    as at one interface between the two glasses (Snell's law through a layer of zero thickness), and a layer of
    zero thickness reflects nothing, so the scene has that one interface; as two, the second had been dropped as
    the first met again, and the lens's second element was air."""
    out = {}
    for a, b in zip(p.surfaces, p.surfaces[1:]):
        if (not a.mirror and not b.mirror and not a.dummy and not b.dummy and a.thickness_mm == 0.0
                and abs(a.n - 1.0) < 1e-12 and a.n_before > 1.0 + 1e-9 and b.n > 1.0 + 1e-9 and _same_geometry(a, b)):
            out[b.index] = a.index
    return out


def _cemented_centres(p, optical: list) -> None:
    """A surface met again inside one glass (no part: the same medium both sides), within a smaller aperture than
    the part placed for it, is where an element of that same glass is cemented in the part's centre (the Canon New
    FD 500 mm f/8 mirror lens: its rear element against the Mangin primary's front, one glass): there the light
    crosses no interface, so the part leaves that centre open (:func:`_leave_centre`). Not where the light meets it
    straight after the part itself (a glass split in two by a surface of no thickness)."""
    for k, s in enumerate(p.surfaces):
        if not s.dummy or s.n <= 1.0 + 1e-9 or k == 0:
            continue
        before = p.surfaces[k - 1]
        twin = next((q for q, _ in optical if not q.mirror and q is not before and _same_geometry(s, q)
                     and s.semi_diameter_mm < q.semi_diameter_mm), None)
        if twin is not None:
            _leave_centre(twin, s.semi_diameter_mm, optical)
            _share_hole(p, twin)


def _glass_label(name, n) -> str:
    return name if name else f"n{n:.5f}"


def build_scene(p, field_deg: float = 0.0, edge_material: str = EDGE_MATERIAL, coating=None) -> dict:
    """The scene dict (TOML tables) of prescription ``p``; warnings are appended to ``p.warnings``."""
    wl = p.wavelength_nm
    require_optical_surface(p.file, p.surfaces)
    largest0 = max((s.semi_diameter_mm for s in p.surfaces if not s.dummy), default=1.0)
    z00 = min(float(s.vertex_mm[2]) for s in p.surfaces if not s.dummy or s.stop) - 1.0
    if p.model is not None:
        from straylight.optics.sequential import holes_for_passing_light

        holes = holes_for_passing_light(p, z00, 1.1 * largest0, source_centre_xy(p))
        by_index = {s.index: s for s in p.surfaces}
        for idx in [i for i in holes if not by_index[i].mirror]:
            # a hole through a Mangin's glass: its front and its mirror back open alike (no glass left without
            # its other face)
            q = by_index[idx]
            after = [s for s in p.surfaces if s.index > idx]
            m = next((s for s in after if s.mirror), None)
            if m is not None and q.n > 1.0 + 1e-9 and all(abs(s.n - q.n) < 1e-12 for s in after if s.index < m.index):
                holes[idx] = holes[m.index] = max(holes[idx], holes.get(m.index, 0.0))
        for idx, r in holes.items():
            m = by_index[idx]
            if m.inner_kind == "hole" and m.inner_radius_mm >= r:
                continue
            m.inner_kind, m.inner_radius_mm = "hole", min(1.05 * r, 0.999 * m.semi_diameter_mm)
            if m.mirror:
                p.warnings.append(f"{m.name}: the file gives this mirror no hole, but the beam passes through it to "
                                  f"a later surface; given a central hole of radius {m.inner_radius_mm:.4g} mm")
                continue
            _share_hole(p, m)
            p.warnings.append(f"{m.name}: the beam after a mirror crosses this lens surface in air on its way to a "
                              f"later surface (an element inside a hole through this glass); given a central hole "
                              f"of radius {m.inner_radius_mm:.4g} mm")
    materials: dict = {}
    parts: list = []
    used = set()
    surfaces = [s for s in p.surfaces if not s.dummy]
    mirrors = [s for s in surfaces if s.mirror]
    placed: list = []
    optical: list = []  # (surface, its part)
    n_al, k_al = aluminium_nk(wl)
    edge_names = {}

    def unique(name):
        base, k = name, 2
        while name in used:
            name = f"{base}_{k}"
            k += 1
        used.add(name)
        return name

    elements: list = []  # (front, back, axis origin, axis, front rim z, back rim z, mechanical radius) of each lens
    in_contact = _in_contact(p)
    for s in surfaces:
        if s.index in in_contact.values():
            continue  # the first of two glasses in contact: the interface is placed at the second (below)
        twin = next((q for q in placed if _same_geometry(s, q) and s.mirror == q.mirror), None)
        if twin is not None and (s.mirror or _same_media(s, twin) or s.semi_diameter_mm >= twin.semi_diameter_mm):
            continue  # the same physical surface met again (a Mangin's or a double pass)
        if twin is not None:
            _leave_centre(twin, s.semi_diameter_mm, optical)
        placed.append(s)
        inner = s.inner_radius_mm if s.inner_kind else 0.0
        outer = s.semi_diameter_mm
        if inner >= outer:
            p.warnings.append(f"{s.name}: hole/obscuration {inner:g} mm >= clear aperture {outer:g} mm; ignored")
            inner = 0.0
        if s.mirror:
            axis = -s.travel_in
            materials.setdefault("aluminium_mirror", {"name": "aluminium_mirror", "wavelength_nm": wl,
                                                      "components": [{"type": "specular", "n": [n_al, k_al]}]})
            part = {"name": unique(s.name), "surface": _surface_table(s, axis, outer, inner),
                    "material": "aluminium_mirror", "back_material": edge_material, "role": "surface"}
            parts.append(part)
            optical.append((s, part))
            if s.inner_kind == "obscuration" and inner > 0:
                parts.append({"name": unique(s.name + "_obscuration"), "surface": _surface_table(s, axis, inner),
                              "material": edge_material, "role": "surface"})
            continue
        # refracting: axis out of the denser medium, whose index is the material's n (docs/optics.md)
        first = next((q for q in p.surfaces if q.index == in_contact[s.index]), None) if s.index in in_contact else None
        n_before = first.n_before if first is not None else s.n_before
        if first is not None:
            outer = min(outer, first.semi_diameter_mm)
            p.warnings.append(f"{first.name}-{s.name}: two glasses in contact (an air gap of no thickness between "
                              "surfaces of one shape): one interface between the two glasses")
        glass_after = s.n > n_before
        axis = -s.travel_in if glass_after else s.travel_in
        n_in, n_out = (s.n, n_before) if glass_after else (n_before, s.n)
        gname = s.glass if glass_after else _glass_before(p, first if first is not None else s)
        key = _glass_label(gname, n_in) + ("" if n_out == 1.0 else f"_in_{n_out:.5f}")
        comp = {"type": "dielectric", "n": round(n_in, 7)}
        if n_out != 1.0:
            comp["n_outside"] = round(n_out, 7)
        coat = coating if n_out == 1.0 else None
        if s.coating and not coating:
            if s.coating.lower() in known_coatings():
                coat = s.coating.lower()
            elif (read := file_coating(s.coating)) is not None:
                coat, label = read
                note = f"coating {s.coating} of the file read as {label} (docs/optics.md)"
                if note not in p.warnings:
                    p.warnings.append(note)
            else:
                p.warnings.append(f"{s.name}: coating {s.coating!r} named in the file is not a known design "
                                  f"({', '.join(sorted(known_coatings()))}); left uncoated (--coating NAME sets one)")
        if coat:
            comp["coating"] = coat
            key += f"_{coat}" if isinstance(coat, str) else f"_mgf2_{round(coat[0]['thickness_nm'] * 4 * MGF2_N)}nm"
        # a label names a glass by its rounded nd.vd ("694.534"): two glasses of one label but not one index (the
        # Fujinon-SW 65 mm's 1.69359 and 1.69350) are two materials, not the first one twice
        base, k = key, 2
        while key in materials and materials[key]["components"] != [comp]:
            key, k = f"{base}_{k}", k + 1
        materials.setdefault(key, {"name": key, "wavelength_nm": wl, "components": [comp]})
        # a mirror on the same surface: a Maksutov's aluminised spot fills the centre; a mirror with a hole (a Mangin
        # primary's back, light leaving through its centre) leaves the glass its hole
        same = [m for m in mirrors if _same_geometry(m, s)]
        spot = max((m.semi_diameter_mm for m in same if not (m.inner_kind == "hole" and m.inner_radius_mm > 0)),
                   default=0.0)
        outer = min([outer] + [m.inner_radius_mm for m in same if m.inner_kind == "hole" and m.inner_radius_mm > 0])
        if spot > 0:
            inner = max(inner, spot)
            s.inner_kind, s.inner_radius_mm = (s.inner_kind or "obscuration"), inner  # as the trace sees it
        parts.append({"name": unique(s.name), "surface": _surface_table(s, axis, outer, inner),
                      "material": key, "role": "surface"})
        optical.append((s, parts[-1]))
        if s.inner_kind == "obscuration" and inner > 0 and spot == 0:
            parts.append({"name": unique(s.name + "_obscuration"), "surface": _surface_table(s, axis, inner),
                          "material": edge_material, "role": "surface"})
    _cemented_centres(p, optical)
    _tighten_mesh_tolerance(optical)
    # lens edges: cylinder between consecutive refracting surfaces with glass between, and flat rings
    for a, b in zip(p.surfaces, p.surfaces[1:]):
        if a.mirror or b.mirror or a.n <= 1.0 + 1e-9 or a.dummy:
            continue
        if abs(abs(np.dot(a.local_z, b.local_z)) - 1) > 1e-9:
            p.warnings.append(f"{a.name}-{b.name}: tilted element; its edge is not modelled")
            continue
        ax = a.local_z * (1 if np.dot(a.local_z, a.travel_in) > 0 else -1)
        off = (b.vertex_mm - a.vertex_mm) - np.dot(b.vertex_mm - a.vertex_mm, ax) * ax
        if np.linalg.norm(off) > 1e-9 or aperture.is_off_axis(a) or aperture.is_off_axis(b):
            p.warnings.append(f"{a.name}-{b.name}: decentred element; its edge is not modelled")
            continue
        edge_key = (tuple(np.round(a.vertex_mm, 6)), tuple(np.round(b.vertex_mm, 6)))
        if edge_key in edge_names or edge_key[::-1] in edge_names:
            continue
        r_mech = max(a.semi_diameter_mm, b.semi_diameter_mm)
        za = float(np.dot(a.vertex_mm, ax)) + sag_mm(a, a.semi_diameter_mm) * float(np.dot(a.local_z, ax))
        zb = float(np.dot(b.vertex_mm, ax)) + sag_mm(b, b.semi_diameter_mm) * float(np.dot(b.local_z, ax))
        za_m = float(np.dot(a.vertex_mm, ax)) + sag_mm(a, min(a.semi_diameter_mm, r_mech)) * float(np.dot(a.local_z, ax))
        zb_m = float(np.dot(b.vertex_mm, ax)) + sag_mm(b, min(b.semi_diameter_mm, r_mech)) * float(np.dot(b.local_z, ax))
        length = zb_m - za_m
        if length <= 1e-6:
            p.warnings.append(f"{a.name}-{b.name}: edge thickness {length:.3g} mm <= 0; its edge is not modelled")
            continue
        origin = a.vertex_mm - np.dot(a.vertex_mm, ax) * ax
        name = unique(f"edge_{a.name}_{b.name}")
        edge_names[edge_key] = name
        parts.append({"name": name, "surface": {"type": "cylinder", "vertex_mm": _v(origin + za_m * ax),
                                                 "axis": _v(ax), "radius_mm": r_mech, "length_mm": length},
                      "material": edge_material, "role": "surface"})
        for s, z_rim, sign in ((a, za, -1.0), (b, zb, 1.0)):
            if s.semi_diameter_mm < r_mech - 1e-9:
                parts.append({"name": unique(f"ring_{s.name}"), "surface": {
                    "type": "plane", "vertex_mm": _v(origin + z_rim * ax), "axis": _v(sign * ax),
                    "outer_radius_mm": r_mech, "inner_radius_mm": s.semi_diameter_mm},
                    "material": edge_material, "role": "surface"})
        elements.append((a, b, origin, ax, za_m, zb_m, r_mech))
    largest = max((s.semi_diameter_mm for s in p.surfaces if not s.dummy), default=1.0)
    # the source's plane, 1 mm before the surface point nearest the object (the stop is a part too), and its centre's
    # shift at an off-axis field (the barrel's front reaches past it)
    z0 = min(_object_side_z(s) for s in p.surfaces if not s.dummy or s.stop) - 1.0
    shift_mm = _field_shift_mm(p, field_deg, z0)
    if not mirrors:
        parts += _spacer_rings(p, elements, edge_material, unique)
        parts += _barrel_front(elements, 1.1 * largest + abs(shift_mm), edge_material, unique)
    # the aperture stop: a black annulus whose hole is the stop's semi-diameter
    stop = next((s for s in p.surfaces if s.stop), None)
    if stop is not None:
        hole = stop.semi_diameter_mm if stop.semi_diameter_from_file else stop.semi_diameter_mm / 1.05
        if stop.mirror and stop.inner_kind == "hole":
            hole = stop.semi_diameter_mm
        toward = -stop.travel_in
        z_rim = 0.0
        if not stop.dummy:
            # in front of the stop surface's part over the whole band from the hole out to its clear aperture, by
            # STOP_CLEARANCE_MM: a concave mirror's rim reaches toward the light past its sag at the hole, and its
            # facets lie up to the mesh tolerance in front of it (optiland's mirror.seq: a ring at the hole's sag
            # let 8 % of the image's rays through from 10.0-10.5 mm, outside the 10 mm stop)
            rim = np.linspace(hole, max(hole, stop.semi_diameter_mm), 65)
            sags = np.asarray(sag_mm(stop, rim))
            z_rim = float(sags[int(np.argmax(sags * float(np.dot(stop.local_z, toward))))])
        centre = stop.vertex_mm + z_rim * stop.local_z + (0.0 if stop.dummy else STOP_CLEARANCE_MM) * toward
        outer = max(1.5 * hole, hole + 1.0)
        if not mirrors and elements:
            outer = max(outer, _stop_ring_reach(p, elements, stop, hole, centre, 1.1 * largest + abs(shift_mm)))
        parts.append({"name": unique("stop"), "surface": {
            "type": "plane", "vertex_mm": _v(centre), "axis": _v(toward),
            "outer_radius_mm": outer, "inner_radius_mm": hole},
            "material": edge_material, "role": "surface"})
    # the detector: an exact disk at the image surface, facing the light, 1.2 x the largest image height; an
    # afocal system (a window, a beam expander) has a beam there, not an image: 1.2 x the largest clear aperture
    # plus the beam's walk over the system's length at the largest field
    f_max = max(p.fields_deg + [abs(field_deg)])
    if math.isfinite(p.efl_mm) and p.image_heights_mm and abs(field_deg) <= max(p.fields_deg):
        # the file's own image heights: a fisheye's field reaches 90 deg and past (the Canon EF 15 mm's 90.015:
        # efl x tan(f) was negative, and the detector the spot's size)
        h_img = max(p.image_heights_mm)
    elif math.isfinite(p.efl_mm) and f_max >= 89.0 and p.image_semi_diameter_mm:
        h_img = p.image_semi_diameter_mm  # an angle past 89 deg has no paraxial image height: the file's image size
    elif math.isfinite(p.efl_mm):
        h_img = abs(p.efl_mm) * math.tan(math.radians(min(f_max, 89.0)))
    else:
        length = max(float(np.linalg.norm(p.image_vertex_mm - s.vertex_mm)) for s in p.surfaces)
        h_img = largest + length * math.tan(math.radians(min(f_max, 80.0)))
    spot = max(0.05 * p.epd_mm, 0.1)
    sensor, why = _on_axis_sensor_mm(p, spot)
    if sensor > h_img:
        h_img = sensor
        p.warnings.append(f"the file's fields are all on axis (no image height): detector image of radius "
                          f"{1.2 * sensor:.4g} mm, 1.2 x {why}")
    r_det = 1.2 * max(h_img, spot)
    det_vertex = p.image_vertex_mm
    virtual = _virtual_image_detector(p, mirrors, largest, f_max)
    if virtual is not None:
        det_vertex, r_det = virtual
    parts.append({"name": unique("image"), "surface": {
        "type": "plane", "vertex_mm": _v(det_vertex), "axis": _v(-p.image_travel_in),
        "outer_radius_mm": r_det}, "role": "detector"})
    # the source: 1 mm on the object side of the surface point nearest the object (its vertex, or the edge of
    # a surface that curves toward the object: a Cassegrain's convex secondary reaches ~90 mm past its
    # vertex; a source at the vertex would start inside it and lose its obscuration)
    f = math.radians(field_deg)
    cx, cy = source_centre_xy(p)
    cy = round(cy + shift_mm, 10) + 0.0
    source = {"type": "collimated_disk", "name": "pupil", "center_mm": [cx, cy, z0], "normal": [0.0, 0.0, 1.0],
              "direction": _v([0.0, math.sin(f), math.cos(f)]), "radius_mm": round(1.1 * largest, 9),
              "power_w": 1.0, "wavelength_nm": wl}
    first = next(s for s in p.surfaces if not s.dummy)
    analysis = {"detector": "image", "entrance": {"center_mm": _v(aperture.centre_mm(first)), "normal": [0.0, 0.0, -1.0],
                                                   "radius_mm": first.semi_diameter_mm}}
    return {"material": materials, "part": _without_empty_annuli(p, parts), "source": [source], "analysis": analysis}


def _virtual_image_detector(p, mirrors, largest_mm: float, field_deg: float):
    """(vertex, radius) mm of the detector of a diverging lens (negative EFL, no mirror), whose image surface the
    file puts at the virtual image, before the lens (Thorlabs' ACN254-100-A: 97.6 mm in front of it, behind the
    source: ghosts found no ray there and the focus check no sequential ray): a plane |EFL| behind the last
    surface, wide enough for the diverging beam (1.2 x (the largest clear aperture x 2 + |EFL| tan F)), warned.
    None for a lens with a real image."""
    if mirrors or not math.isfinite(p.efl_mm) or p.efl_mm >= 0:
        return None
    last = [s for s in p.surfaces if not s.dummy][-1]
    travel = np.asarray(p.image_travel_in, float)
    gap = float(np.dot(p.image_vertex_mm - last.vertex_mm, travel))
    if gap >= 0:
        return None
    d = abs(p.efl_mm)
    vertex = np.asarray(last.vertex_mm, float) + d * travel
    radius = 1.2 * (2.0 * largest_mm + d * math.tan(math.radians(min(field_deg, 80.0))))
    p.warnings.append(f"a diverging lens (EFL {p.efl_mm:.4g} mm): its image is virtual, {-gap:.4g} mm before its "
                      f"last surface; the detector image is a plane {d:.4g} mm behind that surface, of radius "
                      f"{radius:.4g} mm, where the diverging beam lands")
    return vertex, radius


def _without_empty_annuli(p, parts: list) -> list:
    """The parts, less any whose hole is as wide as the part (a surface that another one met again covers whole:
    ZOSPy's TIR prism, its 1 mm exit face inside the 86.6 mm centre the mirror face leaves to it), warned. Such a
    part covers nothing, and the scene refused to load (inner_radius_mm must be < outer_radius_mm)."""
    out = []
    for part in parts:
        surf = part.get("surface", {})
        inner, outer = surf.get("inner_radius_mm"), surf.get("outer_radius_mm")
        if inner is not None and outer is not None and inner >= outer:
            p.warnings.append(f"{part['name']}: its whole aperture ({outer:.4g} mm) lies inside the centre another "
                              f"surface met there takes ({inner:.4g} mm); no part of its own")
            continue
        out.append(part)
    return out


def _surface_z(s, ax, r) -> np.ndarray:
    """Axial positions (along ``ax``) of surface ``s`` at radii ``r`` (its sag, with the vertex)."""
    return float(np.dot(s.vertex_mm, ax)) + np.array([sag_mm(s, float(x)) for x in r]) * float(np.dot(s.local_z, ax))


def _barrel_front(elements, r_source_mm: float, edge_material, unique) -> list:
    """The barrel of a coaxial lens (no mirror), black: its front face, a ring at the front element's rim from the
    largest element's mechanical radius out past the source's disk (1.1 x the largest clear aperture), facing the
    light, so the source's outer ring does not pass around the lens; and its tube, a cylinder just outside the
    largest element from the front rim to the last element's back rim. Behind a wide-angle lens the image (and its
    detector) is larger than the lens: the Fujinon-SW 65 mm's detector took 48 % of its power straight from the
    source around the lens and 37 % through its front element alone, whose diverging light passed outside every
    other element."""
    if not _on_one_axis(elements):
        return []  # left to a CAD housing (CONTRACTS 6.2-6.4)
    ax0, o0 = elements[0][3], elements[0][2]
    r_out = max(e[6] for e in elements)
    z_front = min(e[4] for e in elements)
    z_back = max(e[5] for e in elements)
    r_tube = r_out + max(0.01, 1e-3 * r_out)  # just outside the largest element's edge (no coincident faces)
    out = []
    if r_out < r_source_mm:
        out.append({"name": unique("barrel_front"), "surface": {
            "type": "plane", "vertex_mm": _v(o0 + z_front * ax0), "axis": _v(-ax0),
            "outer_radius_mm": float(1.1 * r_source_mm + 1.0), "inner_radius_mm": float(r_out)},
            "material": edge_material, "role": "surface"})
    if z_back > z_front + 1e-6:  # the tube: a diverging front group's light spread past every element to the image
        out.append({"name": unique("barrel"), "surface": {
            "type": "cylinder", "vertex_mm": _v(o0 + z_front * ax0), "axis": _v(ax0), "radius_mm": float(r_tube),
            "length_mm": float(z_back - z_front)}, "material": edge_material, "role": "surface"})
    return out


def _spacer_rings(p, elements, edge_material, unique) -> list:
    """The barrel's spacers of a coaxial lens (no mirror): each element smaller than the largest gets a black
    ring at its front rim from its own mechanical radius out to the largest's, facing the incoming light, so no
    light passes around it through the air, as a barrel and its spacers stop it (a sequential trace stops it at
    the element's aperture: without the rings two teleconverters, whose middle group is smaller than the front
    one, put 0.87 and 0.94 of the power at focus where the sequential trace puts all of it). A ring that would
    cut another surface or lie in another element's glass there goes to the element's back rim instead; one
    that would cut another element there too is left out, with a warning."""
    if len(elements) < 2 or not _on_one_axis(elements):
        return []  # not one axis: left to a CAD housing (CONTRACTS 6.2-6.4)
    r_out = max(e[6] for e in elements)
    backs = {id(e[1]) for e in elements}
    out = []
    for a, b, origin, ax, z_front, z_back, r_mech in elements:
        if r_mech >= r_out - 1e-9 or id(a) in backs:  # the largest, or cemented behind another (that one's ring)
            continue
        r = np.linspace(r_mech, r_out, 17)
        # at the element's front rim; where a ring there would cut a neighbour (a deep concave face in front: the
        # Fujinon-SW 65 mm's s2, whose light then went around s3-s4), at its back rim
        clash = None
        for z_plane in (z_front, z_back):
            clash = _ring_clash(elements, a, ax, r, z_plane)
            if clash is None:
                out.append({"name": unique(f"spacer_{a.name}"), "surface": {
                    "type": "plane", "vertex_mm": _v(origin + z_plane * ax), "axis": _v(-ax),
                    "outer_radius_mm": float(r_out), "inner_radius_mm": float(r_mech)},
                    "material": edge_material, "role": "surface"})
                break
        if clash is not None:
            p.warnings.append(f"{a.name}-{b.name}: its spacer ring would cut the element {clash}; left out (light may "
                              f"pass around this element)")
    return out


def _on_one_axis(elements) -> bool:
    """Every lens element on the first one's axis line (a coaxial lens)."""
    ax0, o0 = elements[0][3], elements[0][2]
    return all(abs(float(np.dot(e[3], ax0)) - 1.0) <= 1e-9 and np.linalg.norm(e[2] - o0) <= 1e-6 for e in elements)


def _stop_ring_reach(p, elements, stop, hole: float, centre, r_source_mm: float) -> float:
    """How far out the stop's ring of a coaxial lens (no mirror) reaches, so that no light passes beside the stop:
    inside the barrel (between the front and the back element) to its tube, outside it past the source's disk (as
    the barrel's front). Before, it reached 1.5 x its hole, and between a double Gauss's elements, wider than that,
    43 % of the image's power went around it (US 2532751, DiffOptics' example). A ring that would cut an element
    there keeps 1.5 x its hole, warned. 0 where the lens is not on one axis (left to a CAD housing)."""
    if not _on_one_axis(elements):
        return 0.0
    ax0, o0 = elements[0][3], elements[0][2]
    z_stop = float(np.dot(np.asarray(centre, float) - o0, ax0))
    r_out = max(e[6] for e in elements)
    inside = min(e[4] for e in elements) <= z_stop <= max(e[5] for e in elements)
    reach = r_out + max(0.01, 1e-3 * r_out) if inside else 1.1 * r_source_mm + 1.0
    clash = _stop_ring_clash(elements, stop, ax0, np.linspace(hole, reach, 33), z_stop)
    if clash is not None:
        p.warnings.append(f"the stop's ring out to {reach:.4g} mm would cut the element {clash}; it reaches "
                          f"{max(1.5 * hole, hole + 1.0):.4g} mm (light may pass beside the stop)")
        return 0.0
    return float(reach)


def _stop_ring_clash(elements, stop, ax, r, z_plane: float) -> str | None:
    """The element (``"a-b"``) the stop's plane ring at ``z_plane`` over radii ``r`` would cut, other than the one
    whose face is the stop: a face crossing the plane within its clear aperture, the plane between the two faces
    there (in the glass), or the plane between the element's two rims with the ring reaching past a face's clear
    aperture (into its mechanical rim). Beyond a face's clear aperture the element is its flat ring and edge, not
    the surface continued (a double Gauss's deep meniscus, continued, crossed the stop's plane)."""
    for a2, b2, _, _, z_a, z_b, _ in elements:
        if stop in (a2, b2):
            continue
        z1 = z2 = None
        for face in (a2, b2):
            rr = r[r <= face.semi_diameter_mm + 1e-12]
            if len(rr):
                z = _surface_z(face, ax, rr) - z_plane
                if np.any(z * z[0] <= 0):
                    return f"{a2.name}-{b2.name}"
                z1, z2 = (z, z2) if face is a2 else (z1, z)
        if z1 is not None and z2 is not None:
            k = min(len(z1), len(z2))
            if np.any(z1[:k] * z2[:k] <= 0):
                return f"{a2.name}-{b2.name}"
        if min(z_a, z_b) <= z_plane <= max(z_a, z_b) and r.max() > min(a2.semi_diameter_mm, b2.semi_diameter_mm):
            return f"{a2.name}-{b2.name}"
    return None


def _ring_clash(elements, own, ax, r, z_plane: float) -> str | None:
    """The element (``"a-b"``) a plane ring at axial position ``z_plane`` over radii ``r`` would cut (met by either
    of its faces, or inside its glass), other than ``own``'s; None when it cuts none."""
    for a2, b2, _, _, _, _, r2 in elements:
        if a2 is own:
            continue
        rr = r[r <= r2 + 1e-12]
        if len(rr) == 0:
            continue
        z1, z2 = _surface_z(a2, ax, rr) - z_plane, _surface_z(b2, ax, rr) - z_plane
        if np.any(z1 * z1[0] <= 0) or np.any(z2 * z2[0] <= 0) or np.any(z1 * z2 <= 0):
            return f"{a2.name}-{b2.name}"
    return None


def _on_axis_sensor_mm(p, spot_mm: float) -> tuple[float, str]:
    """(half-size, what it is) of a sensor for a lens whose file gives only an on-axis field (no image height: 1.2 x
    0 would leave a detector the size of the spot, which the defocused ghosts miss): the image surface's
    semi-diameter as the file gives it where larger than the spot, else the last lens surface's clear aperture,
    through which every ghost leaves the lens. (0, "") for a file with an off-axis field, an afocal system and a
    system with mirrors (whose image may lie in the incoming beam: a larger disk there would obscure it)."""
    if any(f != 0.0 for f in p.fields_deg) or not math.isfinite(p.efl_mm) or any(s.mirror for s in p.surfaces):
        return 0.0, ""
    given = p.image_semi_diameter_mm
    if given is not None and math.isfinite(given) and given > spot_mm:
        return float(given), f"the image surface's semi-diameter in the file ({given:.4g} mm)"
    last = [s for s in p.surfaces if not s.dummy][-1]
    return float(last.semi_diameter_mm), (f"the last lens surface's clear aperture ({last.name}, "
                                         f"{last.semi_diameter_mm:.4g} mm), through which the ghosts leave the lens")


MESH_TOLERANCE_MM = 0.05  # the scene's default chord tolerance (docs/reference/scene.md, tolerance_mm)
MIN_MESH_TOLERANCE_MM = 1e-3


def _axial_gap_mm(a, b, rho_lo: float, rho_hi: float) -> float:
    """Smallest distance along the common axis between coaxial surfaces ``a`` and ``b`` over the annulus
    ``rho_lo..rho_hi`` their parts share (sampled sags), or inf when they share none or are not coaxial (tilted
    or decentred relative to each other)."""
    if rho_hi <= rho_lo:
        return math.inf
    ax = np.asarray(a.local_z, float)
    if abs(abs(float(np.dot(ax, b.local_z))) - 1.0) > 1e-9:
        return math.inf
    d = np.asarray(b.vertex_mm, float) - np.asarray(a.vertex_mm, float)
    if np.linalg.norm(d - np.dot(d, ax) * ax) > 1e-6:
        return math.inf
    sb = float(np.dot(b.local_z, ax))
    return min(abs(float(np.dot(d, ax)) + sag_mm(b, r) * sb - sag_mm(a, r)) for r in np.linspace(rho_lo, rho_hi, 65))


def _tighten_mesh_tolerance(optical) -> None:
    """Give ``tolerance_mm`` (a quarter of the gap, >= 1 um) to the parts of surfaces closer than 4 x the default
    chord tolerance: the hit search runs on the meshes, and two meshes within their chord error of each other
    (a 0.018 mm air gap between two lenses) would be met in the wrong order; the hit is then refined onto the
    wrong surface and the lens defocuses (by 0.8 mm for such a pair)."""
    for i, (a, pa) in enumerate(optical):
        for b, pb in optical[i + 1:]:
            sa, sb = pa["surface"], pb["surface"]
            if aperture.is_off_axis(a) or aperture.is_off_axis(b):  # the radii the two segments span
                (lo_a, hi_a), (lo_b, hi_b) = aperture.rho_range_mm(a), aperture.rho_range_mm(b)
                gap = _axial_gap_mm(a, b, max(lo_a, lo_b), min(hi_a, hi_b))
            else:
                gap = _axial_gap_mm(a, b, max(sa.get("inner_radius_mm", 0.0), sb.get("inner_radius_mm", 0.0)),
                                    min(sa["outer_radius_mm"], sb["outer_radius_mm"]))
            if gap >= 4.0 * MESH_TOLERANCE_MM:
                continue
            tol = max(float(gap) / 4.0, MIN_MESH_TOLERANCE_MM)
            for part in (pa, pb):
                part["tolerance_mm"] = round(min(part.get("tolerance_mm", MESH_TOLERANCE_MM), tol), 6)


# coatings lens files name, as the lens-design programs' own coating files define them: OpticStudio's
# COATING.DAT "AR" and "MGF2" are one quarter-wave MgF2 layer (at the design wavelength)
FILE_COATINGS = {"AR": "mgf2_quarter_wave", "MGF2": "mgf2_quarter_wave"}


def _object_side_z(s) -> float:
    """The smallest global z of surface ``s`` over its clear aperture (its vertex for a plane)."""
    from straylight.optics.sag import sag_mm

    rho = np.linspace(*aperture.rho_range_mm(s), 33)
    axial = float(np.asarray(s.local_z, float)[2])
    return float(min(float(s.vertex_mm[2]) + sag_mm(s, r) * axial for r in rho))


def _field_shift_mm(p, field_deg: float, z0: float) -> float:
    """The y offset of the ``pupil`` source's centre at an off-axis field: where the field's chief ray, through the
    paraxial entrance pupil's centre, crosses the source plane ``z0``. A wide-angle lens's pupil lies deep inside
    it: at the TH Swiss Irix 11 mm's 62.9 deg edge field the beam crosses the source plane ~50 mm off axis, past
    the disk (1.1 x the largest clear aperture) centred on the axis, and no ray passed. 0 on axis, for a system
    with mirrors (a folded or off-axis pupil) and where the paraxial data give no pupil."""
    if field_deg == 0.0 or p.model is None or abs(field_deg) >= 89.0 or any(s.mirror for s in p.surfaces):
        return 0.0
    first = p.surfaces[0]
    if abs(float(first.local_z[2]) - 1.0) > 1e-12 or np.linalg.norm(first.vertex_mm[:2]) > 1e-9:
        return 0.0
    try:
        z_enp = float(first.vertex_mm[2]) + float(p.model["analysis_results"]["parax_data"].fod.enp_dist) * p.scale
    except Exception:  # noqa: BLE001 - no paraxial pupil
        return 0.0
    if not math.isfinite(z_enp):
        return 0.0
    return -math.tan(math.radians(field_deg)) * (z_enp - z0)


def source_centre_xy(p) -> tuple[float, float]:
    """(x, y) of the ``pupil`` source's centre: the axis, or the centre of the first surface's clear aperture
    when the file decentres it (an off-axis system's entrance segment)."""
    first = next((s for s in p.surfaces if not s.dummy), None)
    if first is None or first.aperture_offset_mm == (0.0, 0.0):
        return 0.0, 0.0
    c = aperture.centre_mm(first)
    return round(float(c[0]), 10) + 0.0, round(float(c[1]), 10) + 0.0


MGF2_N = 1.38  # the index of mgf2_quarter_wave (materials.thin_film)


def file_coating(name: str):
    """(the scene's ``coating`` value, a label) for a coating a lens file names, or None when unknown.

    OpticStudio's COATING.DAT ``AR`` and ``MGF2`` are one quarter-wave MgF2 layer at the traced wavelength
    (``mgf2_quarter_wave``); a name holding ``MGF2`` and a design wavelength, as vendors write them (Edmund's
    ``EO_MGF2(550nm)``), is that layer at its own wavelength: ``[{n = 1.38, thickness_nm = lambda0 / (4 x 1.38)}]``.
    """
    upper = name.strip().upper()
    if upper in FILE_COATINGS:
        return FILE_COATINGS[upper], FILE_COATINGS[upper]
    if "MGF2" in upper:
        m = re.search(r"(\d+(?:\.\d+)?)\s*NM", upper)
        if m is None:
            return "mgf2_quarter_wave", "mgf2_quarter_wave"
        lam0 = float(m.group(1))
        if not 200.0 <= lam0 <= 20000.0:
            return None
        return ([{"n": MGF2_N, "thickness_nm": round(lam0 / (4.0 * MGF2_N), 4)}],
                f"one quarter-wave MgF2 layer at {lam0:g} nm (n = {MGF2_N}, {lam0 / (4.0 * MGF2_N):.4g} nm)")
    return None


def known_coatings() -> set:
    """The named thin-film designs of docs/reference/material.md (coating key)."""
    return {"mgf2_quarter_wave", "broadband_ar"}


def _glass_before(p, s):
    prev = [q for q in p.surfaces if q.index < s.index]
    return prev[-1].glass if prev else None
