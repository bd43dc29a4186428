"""``prescription.json``, ``scene.toml`` and the text of ``optics info`` (docs/optics.md)."""
from __future__ import annotations

import math
from pathlib import Path

import atomicio


def _num(x):
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def prescription_dict(p) -> dict:
    """The ``prescription.json`` document: first-order data (paraxial, rayoptics) and the surface table."""
    return {
        "file": p.file, "units_in_file": p.units_in_file, "wavelength_nm": _num(p.wavelength_nm),
        "efl_mm": _num(p.efl_mm), "bfl_mm": _num(p.bfl_mm), "fno": _num(p.fno), "epd_mm": _num(p.epd_mm),
        "fields_deg": [_num(f) for f in p.fields_deg],
        "surfaces": [{
            "name": s.name, "type": s.type, "radius_mm": _num(s.radius_mm), "conic": _num(s.conic),
            "coefficients": [_num(a) for a in s.coefficients],
            **({"power_terms": [[int(p), _num(a)] for p, a in s.power_terms]} if s.power_terms else {}),
            "thickness_mm": _num(s.thickness_mm),
            "glass": s.glass, "n": _num(s.n), "semi_diameter_mm": _num(s.semi_diameter_mm), "mirror": bool(s.mirror),
            **({"aperture_offset_mm": [_num(v) for v in s.aperture_offset_mm]} if s.aperture_offset_mm != (0.0, 0.0) else {}),
            **({"aperture_half_widths_mm": [_num(v) for v in s.aperture_half_widths_mm]} if s.aperture_half_widths_mm else {}),
        } for s in p.surfaces],
        "warnings": list(p.warnings),
    }


def _show(x, spec) -> str:
    return format(x, spec) if x is not None and math.isfinite(x) else "none (afocal)"


def info_text(p) -> str:
    """First-order data and the surface table, with units and conventions stated."""
    lines = [
        f"{p.file}: {p.format} lens file, lengths in the file in {p.units_in_file}; shown in mm",
        "frame: first surface vertex at the origin, optical axis +z, light from the object toward +z; "
        "radius > 0: centre of curvature on the +z side; thickness to the next vertex (negative after a mirror)",
        f"wavelength  {p.wavelength_nm:.4g} nm",
        f"efl         {_show(p.efl_mm, '.6g')} mm",
        f"bfl         {_show(p.bfl_mm, '.6g')} mm",
        f"f/#         {_show(p.fno, '.4g')}",
        f"epd         {p.epd_mm:.6g} mm",
        f"fields      {', '.join(f'{f:g}' for f in p.fields_deg)} deg",
        "",
        f"{'surface':<12} {'type':<8} {'radius_mm':>13} {'conic':>9} {'thickness_mm':>13} {'glass':<14} "
        f"{'n':>8} {'semi_diam_mm':>12}  notes",
    ]
    for s in p.surfaces:
        r = "inf" if s.radius_mm is None else f"{s.radius_mm:.6g}"
        notes = []
        if s.mirror:
            notes.append("mirror")
        if s.stop:
            notes.append("stop")
        if s.inner_kind:
            notes.append(f"{s.inner_kind} r={s.inner_radius_mm:.4g} mm")
        if s.coefficients:
            notes.append("A4.. = " + ", ".join(f"{a:.4g}" for a in s.coefficients))
        if s.power_terms:
            notes.append(", ".join(f"r^{p}: {a:.4g}" for p, a in s.power_terms))
        if not s.semi_diameter_from_file:
            notes.append("aperture from marginal ray +5%")
        if s.aperture_offset_mm != (0.0, 0.0):
            notes.append("off-axis aperture centred (%.6g, %.6g) mm from the vertex" % s.aperture_offset_mm)
        if s.aperture_half_widths_mm:
            notes.append("rectangular aperture, half-widths %.6g x %.6g mm" % s.aperture_half_widths_mm)
        if any(abs(x) > 1e-9 for x in s.vertex_mm[:2]) or abs(abs(s.local_z[2]) - 1) > 1e-12:
            notes.append("vertex (%.4g, %.4g, %.4g) mm, axis (%.4g, %.4g, %.4g)" % (*s.vertex_mm, *s.local_z))
        lines.append(f"{s.name:<12} {s.type:<8} {r:>13} {s.conic:>9.4g} {s.thickness_mm:>13.6g} "
                     f"{(s.glass or 'air'):<14} {s.n:>8.5f} {s.semi_diameter_mm:>12.5g}  {'; '.join(notes)}")
    for w in p.warnings:
        lines.append(f"warning: {w}")
    return "\n".join(lines)


def _toml_value(v) -> str:
    """One TOML value, inline (tables as inline tables, strings JSON-quoted, which TOML accepts)."""
    import json

    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        f = float(v)
        if not math.isfinite(f):
            raise ValueError(f"non-finite number {v!r} in a scene")
        return repr(int(v)) if isinstance(v, int) else repr(f)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_key(k)} = {_toml_value(x)}" for k, x in v.items()) + "}"
    return "[" + ", ".join(_toml_value(x) for x in v) + "]"


def _key(k: str) -> str:
    import json
    import re

    return k if re.fullmatch(r"[A-Za-z0-9_-]+", k) else json.dumps(k)


def scene_toml(scene: dict, header: str) -> str:
    """The scene as TOML text, inline ``surface`` tables as in docs/reference/scene.md."""
    out = [f"# {line}" for line in header.splitlines()] + [""]
    for key, mat in scene["material"].items():
        out.append(f"[material.{_key(key)}]")
        out += [f"{_key(k)} = {_toml_value(v)}" for k, v in mat.items() if k != "name"]
        out.append("")
    out.append("[analysis]")
    out += [f"{_key(k)} = {_toml_value(v)}" for k, v in scene["analysis"].items()]
    out.append("")
    for table, items in (("part", scene["part"]), ("source", scene["source"])):
        for item in items:
            out.append(f"[[{table}]]")
            out += [f"{_key(k)} = {_toml_value(v)}" for k, v in item.items()]
            out.append("")
    return "\n".join(out)


def write_outputs(p, scene: dict, out_dir) -> None:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    header = (f"imported by straylight optics import from {p.file} ({p.format}, {p.units_in_file}); "
              f"wavelength {p.wavelength_nm:g} nm\nframe: mm, first surface vertex at the origin, light toward +z "
              "(docs/optics.md)")
    atomicio.write_text(out / "scene.toml", scene_toml(scene, header))
    atomicio.write_json(out / "prescription.json", prescription_dict(p))
