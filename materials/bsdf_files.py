"""Tabulated BSDF files in and out: Zemax/Radiant ``.bsdf`` and FRED tabulated BSDF (CONTRACTS §5.2).

Formats (docs/bsdf-files.md has the coordinate figure):

* Zemax/Radiant tabular BSDF (Radiant "BSDF data interchange" format, read by OpticStudio's BSDF
  scatter model): keyword lines ``Source``, ``Symmetry`` (PlaneSymmetrical | Asymmetrical |
  Asymmetrical4D), ``SpectralContent`` (Monochrome), ``ScatterType`` (BRDF | BTDF),
  ``SampleRotation N`` + N values, ``AngleOfIncidence N`` + N values (the *specular* angle),
  ``ScatterAzimuth N`` + N values, ``ScatterRadial N`` + N values, then ``DataBegin`` ...
  ``DataEnd`` with, per rotation and incidence, an optional ``TIS value`` line and N_azimuth rows
  of N_radial values. Radial R is the angle from the specular (or directly transmitted)
  direction; azimuth A = 0 points from it toward the sample normal, A = 90 toward -y of the
  incidence frame (y = z x specular azimuth). Files seen in the wild omit value lines
  (``SampleRotation 1`` alone means rotation 0; ``ScatterAzimuth 2`` alone in a
  PlaneSymmetrical file means 0 and 180) and use tabs or runs of spaces: both are read, as are
  UTF-16 text, comment lines anywhere, lists in any order and ``NaN`` at unmeasured nodes (left
  out; :func:`import_file` reports them among its ``notes``).
* FRED tabulated BSDF: ``type bsdf_data``, ``format angles=deg|sin bsdf=value|log scale=S``
  (``exclude=``, ``num=`` are FRED interpolation hints: read and ignored), then blocks: a
  two-number line (specular theta0, azimuth f0; or a0, b0 with angles=sin) and rows
  ``theta f bsdf`` (or ``a b bsdf``), tab, comma or space separated. theta < 0 with f = 0 is the
  backscatter side. Rows on the horizon (theta = +-90) are dropped. FRED's model is isotropic: blocks are turned so that f0 = 0 and mirrored.

The file's values are used as they are (``scale`` is the file's own instruction and is applied);
``TIS`` lines are kept in the material (``tis``) and reported, never used to rescale.
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

import materials.bsdf_table  # noqa: F401 - registers the component
from materials.albedo import directional_hemispherical_reflectance
from materials.base import MaterialError, brdf_angles
from materials.bsdf_table import rotated
from materials.material import Material
from materials.registry import build_component
from materials.scan import make_scan

ZEMAX_KEYS = ("Source", "Symmetry", "SpectralContent", "ScatterType", "SampleRotation", "AngleOfIncidence",
              "ScatterAzimuth", "ScatterRadial")
_NUM = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eEdD][+-]?\d+)?$")


class BsdfFileError(MaterialError):
    """A BSDF file that cannot be read or is refused; the message names the file and the line."""


def _is_num(tok: str) -> bool:
    return bool(_NUM.match(tok))


def _num(tok: str, where: str) -> float:
    if not _is_num(tok):
        raise BsdfFileError(f"{where}: expected a number, got {tok!r}")
    return float(tok.replace("d", "e").replace("D", "e"))


_NAN = re.compile(r"^[+-]?nan$", re.I)


def _value(tok: str, where: str) -> float:
    """A BSDF value: a number, or NaN (a node the writer had no measurement for)."""
    return math.nan if _NAN.match(tok) else _num(tok, where)


def _tokens(line: str) -> list[str]:
    return [t for t in re.split(r"[\s,;]+", line.strip()) if t]


def _utf16(raw: bytes):
    """'utf-16' (a byte-order mark), 'utf-16-le' / 'utf-16-be' (ASCII text without one: every other
    byte NUL, as Windows programs write "Unicode" text), or None."""
    if raw[:2] in (b"\xff\xfe", b"\xfe\xff"):
        return "utf-16"
    head = raw[:4096]
    if len(head) >= 16 and len(head) % 2 == 0:
        even, odd = head[0::2], head[1::2]
        if odd.count(0) == len(odd) and even.count(0) == 0:
            return "utf-16-le"
        if even.count(0) == len(even) and odd.count(0) == 0:
            return "utf-16-be"
    return None


def read_text(path) -> str:
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise BsdfFileError(f"{path}: cannot read ({exc.strerror or exc})") from None
    utf16 = _utf16(raw)
    if utf16 is not None:
        try:
            return raw.decode(utf16)
        except UnicodeDecodeError:
            raise BsdfFileError(f"{path}: starts as UTF-16 text but does not decode as {utf16}") from None
    if b"\x00" in raw[:4096]:
        raise BsdfFileError(f"{path}: a binary file, not a Zemax tabular BSDF or a FRED tabulated BSDF text")
    for enc in ("utf-8-sig", "latin-1"):
        try:
            return raw.decode(enc)
        except UnicodeDecodeError:
            continue
    raise BsdfFileError(f"{path}: not text")  # pragma: no cover - latin-1 decodes anything


def detect(text: str) -> str:
    """'zemax', 'fred', 'speos' or 'unknown', from the content (never the extension)."""
    lines = [ln.strip() for ln in text.splitlines()[:400]]
    body = [ln for ln in lines if ln and not ln.startswith(("#", "!", ";", "//"))]
    if body and re.match(r"^type\s+bsdf_data\b", body[0], re.I):
        return "fred"
    first = {(_tokens(ln) or [""])[0].lower() for ln in body}
    if {"symmetry", "scattertype"} & first and {"angleofincidence", "scatterradial"} & first:
        return "zemax"
    head = text[:2048]
    if "OPTIS" in head or re.search(r"BSDF surface file", head, re.I) or head.lstrip().startswith("SPEOS"):
        return "speos"
    return "unknown"


# ---------------------------------------------------------------------------------------- Zemax


def _zemax_direction(theta_spec, az, rad):
    """(theta_r, phi_r) radians in the incidence frame of the node at azimuth az, radial rad
    about the specular direction (theta_spec); and the node's cos theta_r."""
    s = np.array([math.sin(theta_spec), 0.0, math.cos(theta_spec)])
    e1 = np.array([-math.cos(theta_spec), 0.0, math.sin(theta_spec)])  # toward the normal
    e2 = np.array([0.0, -1.0, 0.0])  # s x e1
    a, r = np.meshgrid(az, rad, indexing="ij")
    w = (np.cos(r)[..., None] * s + np.sin(r)[..., None] * (np.cos(a)[..., None] * e1 + np.sin(a)[..., None] * e2))
    return np.arccos(np.clip(w[..., 2], -1, 1)), np.arctan2(w[..., 1], w[..., 0]), w[..., 2]


def parse_zemax(text: str, path="file", notes=None) -> dict:
    """The component dict (materials.bsdf_table) of a Zemax/Radiant tabular BSDF text; ``notes``
    (a list) receives one line per thing the file does that the import reports (NaN nodes, a
    closing rotation that disagrees with the first)."""
    notes = [] if notes is None else notes
    lines = text.splitlines()
    head: dict = {}
    counts: dict = {}
    values: dict = {}
    i = 0
    n = len(lines)
    while i < n:
        toks = _tokens(lines[i])
        if not toks or toks[0].startswith("#"):
            i += 1
            continue
        key = toks[0]
        kl = key.lower()
        if kl == "databegin":
            break
        match = next((k for k in ZEMAX_KEYS if k.lower() == kl), None)
        if match in ("Source", "Symmetry", "SpectralContent", "ScatterType"):
            head[match] = toks[1] if len(toks) > 1 else ""
        elif match is not None:
            if len(toks) < 2:
                raise BsdfFileError(f"{path}:{i + 1}: {key} needs a count")
            cnt = int(_num(toks[1], f"{path}:{i + 1}"))
            if cnt < 1:
                raise BsdfFileError(f"{path}:{i + 1}: {key} count must be >= 1")
            counts[match] = cnt
            vals = [_num(t, f"{path}:{i + 1}") for t in toks[2:]]
            j = i + 1
            while len(vals) < cnt and j < n:
                nt = _tokens(lines[j])
                if not nt or nt[0].startswith("#"):  # blank and comment lines may sit anywhere
                    j += 1
                    continue
                if not _is_num(nt[0]):
                    break
                vals += [_num(t, f"{path}:{j + 1}") for t in nt]
                j += 1
            if vals and len(vals) != cnt:
                raise BsdfFileError(f"{path}:{i + 1}: {key} says {cnt} values, found {len(vals)}")
            values[match] = vals or None
            i = j
            continue
        elif kl in ("monochrome",):
            pass
        elif kl.startswith("tristimulus") or kl in ("spectral", "xyz"):
            raise BsdfFileError(f"{path}:{i + 1}: only Monochrome data are supported (found {key})")
        i += 1
    else:
        raise BsdfFileError(f"{path}: no DataBegin line")
    data_start = i + 1
    sym = head.get("Symmetry", "PlaneSymmetrical")
    if sym.lower() not in ("planesymmetrical", "asymmetrical", "asymmetrical4d"):
        raise BsdfFileError(f"{path}: Symmetry {sym!r} is not supported (PlaneSymmetrical, Asymmetrical, Asymmetrical4D)")
    stype = head.get("ScatterType", "BRDF").upper()
    if stype not in ("BRDF", "BTDF"):
        raise BsdfFileError(f"{path}: ScatterType {stype!r}: expected BRDF or BTDF")
    spectral = head.get("SpectralContent", "Monochrome")
    if spectral.lower() != "monochrome":
        raise BsdfFileError(f"{path}: SpectralContent {spectral!r}: only Monochrome data are supported")
    for key in ("AngleOfIncidence", "ScatterRadial", "ScatterAzimuth"):
        if key not in counts:
            raise BsdfFileError(f"{path}: no {key} line")
    plane = sym.lower() == "planesymmetrical"
    n_rot = counts.get("SampleRotation", 1)
    rot = values.get("SampleRotation") or ([0.0] if n_rot == 1 else list(np.linspace(0.0, 360.0, n_rot, endpoint=False)))
    aoi = values.get("AngleOfIncidence")
    rad = values.get("ScatterRadial")
    if aoi is None or rad is None:
        raise BsdfFileError(f"{path}: AngleOfIncidence and ScatterRadial need their values")
    n_az = counts["ScatterAzimuth"]
    az = values.get("ScatterAzimuth") or list(np.linspace(0.0, 180.0 if plane else 360.0, n_az,
                                                              endpoint=plane))
    if any(a < 0 or a >= 90 for a in aoi):
        raise BsdfFileError(f"{path}: AngleOfIncidence values must lie in [0, 90), got {aoi}")
    for key, vals in (("AngleOfIncidence", aoi), ("SampleRotation", rot)):
        twice = sorted({v for v in vals if list(vals).count(v) > 1})
        if twice:
            raise BsdfFileError(f"{path}: {key} lists {twice[0]:g} deg more than once")
    # data: numbers in order, with 'TIS v' markers
    per_block = n_az * len(rad)
    n_blocks = len(rot) * len(aoi)
    nums: list[float] = []
    tis: list[float | None] = []
    tis_at: list[tuple] = []  # (index into nums, line) of each TIS line: where a block starts
    rows: list[tuple] = []  # (line, values on it)
    ended = False
    for k in range(data_start, n):
        toks = _tokens(lines[k])
        if not toks or toks[0].startswith("#"):
            continue
        if toks[0].lower() == "dataend":
            ended = True
            break
        if toks[0].lower() == "tis":
            tis_at.append((len(nums), k + 1))
            # a TIS line without its value keeps its block's place (None: the later blocks keep theirs)
            tis.append(_num(toks[1], f"{path}:{k + 1}") if len(toks) > 1 else None)
            continue
        if toks[0].lower() in ("monochrome", "databegin"):
            continue
        nums += [_value(t, f"{path}:{k + 1}") for t in toks]
        rows.append((k + 1, len(toks)))
    if len(nums) != per_block * n_blocks:
        where = _count_mismatch(tis_at, rows, len(nums), per_block, n_blocks, len(rad), rot, aoi)
        body = "\n".join(lines[line - 1] for line, _ in rows[:50])
        if re.search(r"\d,\d", body) and "." not in body:
            where += "; the numbers use decimal commas (3,5E-02): the format needs decimal points"
        raise BsdfFileError(
            f"{path}: the data hold {len(nums)} values, expected {n_blocks} blocks x {n_az} azimuths x "
            f"{len(rad)} radial angles = {per_block * n_blocks}" + ("" if ended else " (no DataEnd line)") + where)
    data = np.asarray(nums).reshape(len(rot), len(aoi), n_az, len(rad))
    nan = np.isnan(data)
    if np.any(np.isinf(data)) or np.any(data < 0):
        bad = np.argwhere(np.isinf(data) | (data < 0))[0]
        raise BsdfFileError(f"{path}: negative or non-finite BSDF value at rotation {rot[bad[0]]:g} deg, "
                            f"incidence {aoi[bad[1]]:g} deg, azimuth {az[bad[2]]:g}, radial {rad[bad[3]]:g}")
    blocks = []
    n_nan = 0
    for r in range(len(rot)):
        for j, a in enumerate(aoi):
            th, ph, cz = _zemax_direction(math.radians(a), np.radians(az), np.radians(rad))
            above = cz > 1e-6
            keep = above & ~nan[r, j]
            n_nan += int(np.count_nonzero(above & nan[r, j]))
            if not np.any(keep):
                raise BsdfFileError(f"{path}: no value above the horizon at rotation {rot[r]:g} deg, incidence "
                                    f"{a:g} deg (every node there is NaN)")
            blocks.append({"theta_r_deg": np.degrees(th[keep]).tolist(), "phi_r_deg": np.degrees(ph[keep]).tolist(),
                           "bsdf_per_sr": data[r, j][keep].tolist()})
    if n_nan:
        notes.append(f"{n_nan} nodes above the horizon hold NaN (no measurement) and are left out: the table "
                     "interpolates over the measured nodes and holds the nearest one beyond them")
    _note_closing_rotation(rot, az, data, notes)
    # the format does not order its lists: rotations and incidences are sorted with their blocks
    r_order, a_order = np.argsort(rot, kind="stable"), np.argsort(aoi, kind="stable")
    blocks = [blocks[o * len(aoi) + j] for o in r_order for j in a_order]
    tis = [tis[o * len(aoi) + j] for o in r_order for j in a_order] if len(tis) == n_blocks else tis
    rot, aoi = [rot[o] for o in r_order], [aoi[j] for j in a_order]
    comp = {"type": "bsdf_table", "scatter": stype.lower(), "symmetry": "plane" if plane else "none",
            "rotation_deg": [float(v) for v in rot], "theta_i_deg": [float(v) for v in aoi], "blocks": blocks}
    if any(v is not None for v in tis):
        comp["tis"] = tis
    return comp


def _count_mismatch(tis_at, rows, n_values, per_block, n_blocks, n_rad, rot, aoi) -> str:
    """Where a Zemax data section's count goes wrong, for the one-line refusal: the first block
    (between TIS lines) of the wrong size, else the first row that is not one radial scan."""
    if len(tis_at) == n_blocks:
        ends = [start for start, _ in tis_at[1:]] + [n_values]
        for b, ((start, line), end) in enumerate(zip(tis_at, ends)):
            if end - start != per_block:
                r, j = divmod(b, len(aoi))
                return (f"; the block from line {line} (rotation {rot[r]:g} deg, incidence {aoi[j]:g} deg) "
                        f"holds {end - start}")
    odd = [(line, c) for line, c in rows if c != n_rad]
    if odd and len(odd) <= len(rows) // 2:
        return f"; line {odd[0][0]} holds {odd[0][1]} values, not one per radial angle ({n_rad})"
    return ""


def _note_closing_rotation(rot, az, data, notes) -> None:
    """A closing duplicate rotation (first + 360) is not a node of its own (rotations are periodic):
    say so when its values differ from the first rotation's, and whether they are its azimuth mirror."""
    order = np.argsort(rot)
    first, last = int(order[0]), int(order[-1])
    if len(rot) < 2 or rot[last] < rot[first] + 360.0 - 1e-9:
        return
    a, b = data[first], data[last]
    both = ~np.isnan(a) & ~np.isnan(b)
    differ = both & (np.abs(a - b) > 1e-3 * np.maximum(np.abs(a), np.abs(b)) + 1e-30)
    if not np.any(differ):
        return
    line = (f"sample rotation {rot[last]:g} deg repeats rotation {rot[first]:g} deg but {int(differ.sum())} of "
            f"{int(both.sum())} values differ; the table uses rotation {rot[first]:g} deg's")
    mirror = [list(az).index((360.0 - x) % 360.0) if (360.0 - x) % 360.0 in az else -1 for x in az]
    if -1 not in mirror:
        m = a[:, mirror, :]
        ok = ~np.isnan(m) & ~np.isnan(b)
        if np.all(np.abs(m[ok] - b[ok]) <= 1e-3 * np.maximum(np.abs(m[ok]), np.abs(b[ok])) + 1e-30):
            line += " (the file's last rotation is its first mirrored in azimuth, A -> 360 - A)"
    notes.append(line)


# ---------------------------------------------------------------------------------------- FRED


def parse_fred(text: str, path="file", notes=None) -> dict:
    """The component dict of a FRED tabulated BSDF text (isotropic: symmetry 'plane'); ``notes`` as
    for :func:`parse_zemax` (rows whose BSDF is NaN)."""
    notes = [] if notes is None else notes
    lines = text.splitlines()
    fmt = {"angles": "deg", "bsdf": "value", "scale": "1"}
    blocks: list = []
    seen_type = False
    for k, line in enumerate(lines):
        s = line.strip()
        if not s or s.startswith(("#", "!", ";", "//")):
            continue
        low = s.lower()
        if low.startswith("type"):
            if not re.match(r"^type\s+bsdf_data\b", low):
                raise BsdfFileError(f"{path}:{k + 1}: expected 'type bsdf_data'")
            seen_type = True
            continue
        if low.startswith("format"):
            for part in s.split()[1:]:
                if "=" in part:
                    key, val = part.split("=", 1)
                    fmt[key.lower()] = val
            continue
        toks = _tokens(s)
        nums = [(_value if j == 2 else _num)(t, f"{path}:{k + 1}") for j, t in enumerate(toks)]
        if len(nums) == 2:
            blocks.append((nums, [], k + 1))
        elif len(nums) == 3:
            if not blocks:
                raise BsdfFileError(f"{path}:{k + 1}: a data row before the first specular-angle line")
            blocks[-1][1].append(nums)
        else:
            raise BsdfFileError(f"{path}:{k + 1}: expected 2 numbers (specular direction) or 3 (theta, f, bsdf)")
    if not seen_type:
        raise BsdfFileError(f"{path}: no 'type bsdf_data' line")
    angles = fmt["angles"].lower()
    kind = fmt["bsdf"].lower()
    if angles not in ("deg", "sin") or kind not in ("value", "log"):
        raise BsdfFileError(f"{path}: format angles={fmt['angles']} bsdf={fmt['bsdf']}: expected angles=deg|sin, bsdf=value|log")
    try:
        scale = float(fmt["scale"])
    except ValueError:
        raise BsdfFileError(f"{path}: format scale={fmt['scale']!r} is not a number") from None
    if not blocks:
        raise BsdfFileError(f"{path}: no data blocks")
    merged: dict = {}
    n_nan = 0
    for (h0, h1), rows, line_no in blocks:
        if not rows:
            raise BsdfFileError(f"{path}:{line_no}: specular direction with no data rows")
        r = np.asarray(rows, float)
        measured = ~np.isnan(r[:, 2])
        n_nan += int(np.count_nonzero(~measured))
        if not np.any(measured):
            raise BsdfFileError(f"{path}:{line_no}: every BSDF value of this block is NaN")
        r = r[measured]
        if angles == "deg":
            th0, f0 = math.radians(h0), math.radians(h1)
            th, f = np.radians(r[:, 0]), np.radians(r[:, 1])
            sx, sy = np.sin(th) * np.cos(f), np.sin(th) * np.sin(f)
            b0 = math.sin(th0)
        else:  # a = sin f sin theta, b = cos f sin theta
            a0, bb0 = h0, h1
            b0, f0 = math.hypot(a0, bb0), math.atan2(a0, bb0)
            sx, sy = r[:, 1], r[:, 0]
            th0 = math.asin(min(b0, 1.0))
        if b0 < 0:  # a negative specular angle: the same incidence seen from the other side
            b0, f0, th0 = -b0, f0 + math.pi, -th0
        cf, sf = math.cos(f0), math.sin(f0)
        x, y = cf * sx + sf * sy, -sf * sx + cf * sy
        rho = np.hypot(x, y)
        vals = (10.0 ** r[:, 2] if kind == "log" else r[:, 2]) * scale
        keep = rho < 1.0 - 1e-9  # rows at theta = +-90 deg (grazing, on the horizon) carry no energy: dropped
        if not np.any(keep):
            raise BsdfFileError(f"{path}:{line_no}: every scatter direction of this block is on the horizon (90 deg)")
        x, y, rho, vals = x[keep], y[keep], rho[keep], vals[keep]
        if np.any(~np.isfinite(vals)) or np.any(vals < 0):
            raise BsdfFileError(f"{path}:{line_no}: negative or non-finite BSDF values in this block")
        ti = round(math.degrees(th0), 9)
        if not 0 <= ti < 90:
            raise BsdfFileError(f"{path}:{line_no}: specular angle {ti:g} deg outside [0, 90)")
        ent = merged.setdefault(ti, ([], [], []))
        ent[0].extend(np.degrees(np.arcsin(rho)).tolist())
        ent[1].extend(np.degrees(np.arctan2(y, x)).tolist())
        ent[2].extend(vals.tolist())
    if n_nan:
        notes.append(f"{n_nan} rows hold NaN (no measurement) and are left out")
    tis = sorted(merged)
    return {"type": "bsdf_table", "scatter": "brdf", "symmetry": "plane", "rotation_deg": [0.0],
            "theta_i_deg": tis,
            "blocks": [{"theta_r_deg": merged[t][0], "phi_r_deg": merged[t][1], "bsdf_per_sr": merged[t][2]}
                       for t in tis]}


# ---------------------------------------------------------------------------------------- import


def import_file(path, name=None):
    """(Material, report dict) from a Zemax or FRED file; refuses other files and non-physical data."""


    path = Path(path)
    text = read_text(path)
    kind = detect(text)
    if kind == "speos":
        raise BsdfFileError(f"{path}: a Speos/OPTIS BSDF file: not supported (import reads Zemax tabular .bsdf "
                            "and FRED tabulated BSDF text)")
    if kind == "unknown":
        raise BsdfFileError(f"{path}: not a Zemax tabular BSDF (Symmetry/ScatterType/AngleOfIncidence/DataBegin) "
                            "nor a FRED tabulated BSDF ('type bsdf_data')")
    notes: list = []
    comp = parse_zemax(text, path, notes) if kind == "zemax" else parse_fred(text, path, notes)
    table = build_component(comp, where=str(path))
    table.check_energy_table(str(path))
    material = Material(name=name or path.stem, wavelength_nm=None, components=(table,),
                        provenance=f"imported from {path.name} ({'Zemax tabular BSDF' if kind == 'zemax' else 'FRED tabulated BSDF'})")
    report = {"format": kind, "scatter": table.scatter, "symmetry": table.symmetry,
              "rotation_deg": list(table.rotation_deg), "theta_i_deg": list(table.theta_i_deg),
              "tis_in_file": list(table.tis) if table.tis else None,
              "dhr": [table.dhr(list(table.theta_i_deg), r).tolist() for r in table._rotations], "notes": notes}
    return material, report


# ---------------------------------------------------------------------------------------- export

DEFAULT_AOI_DEG = tuple(float(a) for a in range(0, 70, 5)) + tuple(70.0 + 2.5 * k for k in range(7)) + (86.0, 87.0, 88.0, 89.0)
DEFAULT_RADIAL_DEG = (0.0, 0.05, 0.1, 0.2, 0.3, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0, 5.0, 6.0, 7.5, 10.0, 12.5, 15.0,
                      17.5) + tuple(float(r) for r in range(20, 181, 5))


def _lobe_radial_deg(material, aoi_deg=()) -> list[float]:
    """Radial angles that resolve the material's narrowest in-plane lobe: the default set, fractions
    of its half-width at half maximum at a few incidences, and for each incidence the radial angles
    1 deg short of the horizon on both sides of the plane of incidence (90 - aoi - 1, 90 + aoi - 1)."""

    extra = []
    fine = np.radians(np.concatenate([np.linspace(0.0, 2.0, 201), np.linspace(2.0, 89.0, 175)]))
    for ti in (0.0, 30.0, 60.0):
        t = math.radians(ti)
        f = brdf_angles(material, t, np.abs(t + fine), np.where(t + fine >= 0, 0.0, np.pi))
        if f.max() <= 0:
            continue
        half = fine[np.nonzero(f >= 0.5 * f.max())[0][-1]]
        hw = math.degrees(max(half, 1e-4))
        extra += [hw * k for k in (0.25, 0.5, 1.0, 2.0, 4.0)]
    for a in aoi_deg:
        extra += [v for v in (90.0 - a - 1.0, 90.0 + a - 1.0) if 0.5 < v < 179.5]
    out = sorted({round(v, 4) for v in list(DEFAULT_RADIAL_DEG) + [e for e in extra if e < 180]})
    return out


def _dhr(material, theta_i_deg):
    return np.asarray(material.albedo(np.radians(theta_i_deg), "u"), float)


def _tables(material):
    return [c for c in material.components if getattr(c, "type_name", "") == "bsdf_table"]


def _fmt(v: float) -> str:
    return f"{v:.6e}"


def _f_at(material, theta_i_deg, az_deg, rad_deg, rotation_deg=None):
    """Material BRDF on a Zemax (azimuth x radial) grid about the specular direction (0 below the horizon)."""

    th, ph, cz = _zemax_direction(math.radians(theta_i_deg), np.radians(az_deg), np.radians(rad_deg))
    model = material if rotation_deg is None else rotated(material, rotation_deg)
    ti = math.radians(theta_i_deg)
    wi = np.tile([-math.sin(ti), 0.0, math.cos(ti)], (th.size, 1))
    wo = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=-1).reshape(-1, 3)
    # a node on the horizon (|cos| < 1e-9, e.g. R = 90 at normal incidence) gets the limit from just above it
    edge = (np.abs(cz) <= 1e-9).reshape(-1)
    if np.any(edge):
        wo[edge, 2] = 1e-7
        wo[edge] /= np.linalg.norm(wo[edge], axis=1, keepdims=True)
    f = model.brdf(wi, wo, "u").reshape(th.shape)
    return np.where(cz > -1e-9, f, 0.0)


def export_zemax(material, aoi_deg=None, radial_deg=None, azimuth_deg=None) -> str:
    """Zemax tabular BSDF text: PlaneSymmetrical for an isotropic material, Asymmetrical4D for an
    imported anisotropic table (its rotations). TIS lines: the material's own DHR at each incidence."""
    tables = _tables(material)
    aniso = any(t.anisotropic or t.symmetry == "none" for t in tables)
    stype = "BTDF" if tables and all(t.scatter == "btdf" for t in tables) else "BRDF"
    aoi = list(aoi_deg) if aoi_deg else (sorted({*DEFAULT_AOI_DEG, *[a for t in tables for a in t.theta_i_deg]}))
    rad = list(radial_deg) if radial_deg else _lobe_radial_deg(material, aoi)
    az = list(azimuth_deg) if azimuth_deg else (list(np.arange(0.0, 360.0, 10.0)) if aniso else list(np.arange(0.0, 181.0, 10.0)))
    rots = [float(r) for r in tables[0]._rotations] if aniso and tables else [0.0]

    def row(vals):
        return "\t".join(f"{v:g}" for v in vals)

    out = ["# written by straylight material export", f"# material: {material.name}",
           "# TIS: the material's directional-hemispherical reflectance at each incidence (hemisphere quadrature)",
           "Source\tMeasured" if tables else "Source\tModeled",
           f"Symmetry\t{'Asymmetrical4D' if aniso else 'PlaneSymmetrical'}", "SpectralContent\tMonochrome",
           f"ScatterType\t{stype}", f"SampleRotation\t{len(rots)}", row(rots), f"AngleOfIncidence\t{len(aoi)}",
           row(aoi), f"ScatterAzimuth\t{len(az)}", row(az), f"ScatterRadial\t{len(rad)}", row(rad), "",
           "Monochrome", "DataBegin"]
    for r in rots:
        for a in aoi:
            if aniso:
                tis = float(material_dhr_rotated(material, a, r))
                grid = _f_at(material, a, az, rad, r)
            else:
                tis = float(_dhr(material, [a])[0])
                grid = _f_at(material, a, az, rad)
            out.append(f"TIS\t{tis:.6g}")
            out += ["\t".join(_fmt(v) for v in line) for line in grid]
    out.append("DataEnd")
    return "\n".join(out) + "\n"


def material_dhr_rotated(material, theta_i_deg, rotation_deg):

    return directional_hemispherical_reflectance(rotated(material, rotation_deg), math.radians(theta_i_deg), "u")


def export_fred(material, aoi_deg=None, scatter_deg=None) -> str:
    """FRED tabulated BSDF text: in-plane scans (theta from -89.5 to 89.5, denser near specular)
    at each specular angle. FRED's tabulated model is isotropic: an anisotropic table is written at
    its rotation 0 (the caller warns)."""

    tables = _tables(material)
    aoi = list(aoi_deg) if aoi_deg else sorted({*DEFAULT_AOI_DEG, *[a for t in tables for a in t.theta_i_deg]})
    out = ["type bsdf_data", "format angles=deg bsdf=value scale=1"]
    for a in aoi:
        if scatter_deg:
            th = np.asarray(sorted(scatter_deg), float)
        else:
            offs = np.array([0.0] + [s * o for o in (0.05, 0.1, 0.2, 0.3, 0.5, 0.75, 1, 1.5, 2, 3, 4, 5, 7.5)
                                     for s in (-1, 1)])
            th = np.unique(np.round(np.concatenate([np.linspace(-89.5, 89.5, 180), a + offs]), 4))
            th = th[(th >= -89.5) & (th <= 89.5)]
        model = material
        if tables and tables[0].anisotropic:
        
            model = rotated(material, 0.0)
        f = brdf_angles(model, math.radians(a), np.radians(np.abs(th)), np.where(th >= 0, 0.0, np.pi))
        out.append(f"{a:g}\t0")
        out += [f"{t:g}\t0\t{v:.6e}" for t, v in zip(th, f)]
    return "\n".join(out) + "\n"


# ---------------------------------------------------------------------------------------- fit


def wavelength_from_comments(text: str):
    """A wavelength stated in a file's comment lines ('650 nm'), or None."""
    for line in text.splitlines()[:80]:
        if line.lstrip().startswith(("#", "!")):
            m = re.search(r"(\d{3,4}(?:\.\d+)?)\s*nm\b", line)
            if m:
                return float(m.group(1))
    return None


def scan_from_file(path, wavelength_nm=None):
    """A measured scan (materials.scan.Scan) from a Zemax or FRED file: the nodes in the plane of
    incidence of every incidence (rotation 0 of an anisotropic file), polarization 'u', std unknown
    (the fit then uses its default relative std). ``wavelength_nm``: given, else read from the file's
    comments ('650 nm'), else an error naming what to pass."""


    path = Path(path)
    text = read_text(path)
    kind = detect(text)
    if kind not in ("zemax", "fred"):
        raise BsdfFileError(f"{path}: not a Zemax tabular BSDF nor a FRED tabulated BSDF")
    comp = parse_zemax(text, path) if kind == "zemax" else parse_fred(text, path)
    if comp["scatter"] != "brdf":
        raise BsdfFileError(f"{path}: a BTDF file: fit reads reflectance (BRDF) files")
    wl = wavelength_nm if wavelength_nm is not None else wavelength_from_comments(text)
    if wl is None:
        raise BsdfFileError(f"{path}: the file states no wavelength: pass --wavelength-nm")
    n_ti = len(comp["theta_i_deg"])
    ti_col, tr_col, ph_col, v_col = [], [], [], []
    for j, ti in enumerate(comp["theta_i_deg"]):
        b = comp["blocks"][j]  # rotation 0 (the first rotation) of the file
        th = np.asarray(b["theta_r_deg"])
        ph = np.mod(np.asarray(b["phi_r_deg"]), 360.0)
        v = np.asarray(b["bsdf_per_sr"])
        inplane = (np.minimum(np.abs(ph), np.abs(ph - 360.0)) < 1e-6) | (np.abs(ph - 180.0) < 1e-6) | (th < 1e-9)
        keep = inplane & (v > 0) & (th < 89.9)
        signed = np.where(np.abs(ph - 180.0) < 1e-6, -th, th)[keep]
        signed, idx = np.unique(np.round(signed, 9), return_index=True)
        ti_col += [ti] * len(signed)
        tr_col += list(signed)
        ph_col += [0.0] * len(signed)
        v_col += list(v[keep][idx])
    if not v_col:
        raise BsdfFileError(f"{path}: no positive values in the plane of incidence to fit")
    del n_ti
    return make_scan(wavelength_nm=wl, polarization="u", theta_i_deg=ti_col, theta_r_deg=tr_col, phi_r_deg=ph_col,
                     brdf_per_sr=v_col, metadata={"sample": path.stem, "source": f"{kind} tabulated BSDF {path.name}"})
