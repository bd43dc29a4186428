"""Read a lens-design file (CODE V ``.seq``, Zemax ``.zmx``) into a list of surfaces in the scene frame.

The parsing is rayoptics' (BSD-3, M. Hayford): its CODE V and Zemax readers, its opticalglass catalogues
(Schott, Ohara, Hoya, CDGM, Sumita...) for the media, its global surface transforms for decentres, tilts and
coordinate breaks, and its paraxial first-order data. This module turns its model, once, into the frame of
docs/optics.md: millimetres, the first surface's vertex at the origin, light from the object toward +z.

What rayoptics does not keep (CODE V ``CIR ... OBS`` / ``CIR ... HOL``, Zemax ``OBSC`` / annular ``CLAP``)
is read from the file's text here (:func:`_obstructions`).
"""
from __future__ import annotations

import logging
import math
import re
import tempfile
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import atomicio
from straylight.optics.other_materials import medium as other_medium
from straylight.optics.sag import sag_mm


class OpticsFileError(ValueError):
    """A lens file that cannot be imported (one line: what and where)."""


class _ReaderFailure(OpticsFileError):
    """rayoptics failed on the file (parsing it or tracing its fields), as opposed to a refusal of ours."""


def _first_line(exc: BaseException) -> str:
    """An exception's message's first line (its type's name when it has none): rayoptics' failures, in one line."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def _rayoptics_update(opm, path: Path) -> None:
    """``opm.update_model()``, a failure of rayoptics' field aiming one line naming the file."""
    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            opm.update_model()
    except Exception as exc:  # noqa: BLE001 - any rayoptics failure is one line naming the file
        raise _ReaderFailure(f"{path}: rayoptics could not trace the file's fields "
                             f"({type(exc).__name__}: {_first_line(exc)})") from None


UNIT_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "inches": 25.4, "in": 25.4, "meters": 1000.0}


@dataclass
class OpticalSurface:
    """One sequential surface, in the scene frame (mm)."""

    index: int                      # sequential number in the file (object = 0)
    name: str
    type: str                       # sphere | conic | asphere | plane
    radius_mm: float | None         # None: flat
    conic: float
    coefficients: list              # [A4, A6, ...] in mm^-3, mm^-5 ...
    thickness_mm: float             # to the next vertex, the file's sign convention
    glass: str | None               # medium after the surface (None: air)
    n: float                        # index after the surface at the wavelength
    n_before: float
    mirror: bool
    semi_diameter_mm: float
    semi_diameter_from_file: bool
    vertex_mm: np.ndarray
    local_z: np.ndarray             # the surface's own +z axis (sag direction) in the scene frame
    travel_in: np.ndarray           # direction light travels arriving at the surface (unit, scene frame)
    stop: bool = False
    inner_radius_mm: float = 0.0    # hole or obscuration radius
    inner_kind: str = ""            # "hole" | "obscuration" | ""
    coating: str | None = None
    dummy: bool = False             # same medium both sides, not a mirror: no part
    power_terms: list = field(default_factory=list)  # [(p, a_p)]: further sag terms a_p rho^p (odd, r^2), mm^(1-p)
    aperture_offset_mm: tuple = (0.0, 0.0)  # clear aperture's centre in the surface's own x, y (off-axis segment)
    aperture_half_widths_mm: tuple = ()     # (hx, hy): a rectangular clear aperture about that centre
    local_x: np.ndarray | None = None       # the surface's own +x axis in the scene frame (for the two above)


@dataclass
class Prescription:
    file: str
    format: str                     # "CODE V" | "Zemax"
    units_in_file: str
    wavelength_nm: float
    efl_mm: float
    bfl_mm: float
    fno: float
    epd_mm: float
    fields_deg: list
    surfaces: list                  # OpticalSurface, object and image excluded
    image_vertex_mm: np.ndarray
    image_travel_in: np.ndarray
    image_local_z: np.ndarray
    stop_semi_diameter_mm: float | None
    warnings: list = field(default_factory=list)
    model: object = None            # the rayoptics OpticalModel (wavelength set to wavelength_nm)
    scale: float = 1.0              # mm per file unit


def sniff_format(raw: bytes, path: Path) -> tuple[str, str]:
    """("zmx" | "seq", decoded text), recognised by content (UTF-16 as OpticStudio writes it, UTF-8, Latin-1)."""
    if raw[:2] in (b"\xff\xfe", b"\xfe\xff"):
        text = raw.decode("utf-16", errors="replace")
    elif len(raw) > 3 and raw[1:2] == b"\x00" and raw[3:4] == b"\x00":
        text = raw.decode("utf-16-le", errors="replace")
    else:
        try:
            text = raw.decode("utf-8-sig")
        except UnicodeDecodeError:
            text = raw.decode("latin-1")
    if "\x00" in text[:200]:
        raise OpticsFileError(f"{path}: binary file, not a lens file (CODE V .seq or Zemax .zmx text)")
    heads = [ln.strip().split()[0].upper() for ln in text.splitlines()[:400] if ln.strip()]
    if "SURF" in heads and any(h in heads for h in ("VERS", "MODE", "UNIT", "ENPD", "WAVM", "TYPE")):
        return "zmx", text
    codev = {"S", "SO", "SI", "LEN", "EPD", "WL", "DIM", "YAN", "XAN", "FNO", "TIT", "RDM", "S1", "SO"}
    if sum(h.rstrip(";") in codev for h in heads) >= 3:
        return "seq", text
    if path.suffix.lower() in (".zos", ".zar"):
        raise OpticsFileError(f"{path}: binary OpticStudio archive (.{path.suffix[1:]}); export the lens as a .zmx file")
    raise OpticsFileError(f"{path}: not a CODE V sequence file (.seq) or a Zemax lens file (.zmx): "
                          "no SURF or S/SO/SI commands found")


def _zemax_blocks(text: str) -> list:
    """The Zemax file's surface blocks: ``[(surface number, line number of its SURF line, [(line number, words)])]``
    (lines numbered from 1). OpticStudio indents a surface's lines; a block ends at the next ``SURF`` or at an
    unindented command after indented ones (``TOL``, ``MNUM``, ``CONF``... the file's trailing sections)."""
    blocks: list = []
    for n, line in enumerate(text.splitlines(), start=1):
        words = line.split()
        if not words:
            continue
        if words[0].upper() == "SURF":
            blocks.append([words[1] if len(words) > 1 else "?", n, [], True])
        elif blocks and blocks[-1][3]:
            body = blocks[-1][2]
            if body and body[0][2] and not line[:1].isspace():
                blocks[-1][3] = False
            else:
                body.append((n, [w.upper() if k == 0 else w for k, w in enumerate(words)], line[:1].isspace()))
    return [(k, n, [(m, w) for m, w, _ in body]) for k, n, body, _ in blocks]


#: commands a whole surface may lack (hand-written files: a stop without TYPE or CURV, a surface in air without
#: GLAS), not signs of a cut whatever the file's other surfaces have
OPTIONAL_SURFACE_COMMANDS = frozenset({"TYPE", "CURV", "GLAS", "STOP"})


def _zemax_truncation(text: str) -> str | None:
    """Where a Zemax file stops inside its surface list (a download cut short, a converter that stopped), as
    ``"line N: ..."``; None for a whole file. Signs, each absent from every whole file of the corpus (1218
    OpticsDatabase files, docs/optics.md): the text ends inside a character (UTF-16 cut at an odd byte); the file
    ends inside its last surface's block and that block lacks a command every other surface has, or its last line
    has fewer fields than that command has on every other surface, or is a lone fragment of a command name; the
    last surface (the image) has a glass or a thickness after it, as a lens surface has."""
    lines = text.splitlines()
    last = max((n for n, ln in enumerate(lines, start=1) if ln.strip()), default=0)
    if text.rstrip().endswith("\ufffd"):
        return f"line {last}: the file ends inside a character (cut short?)"
    blocks = _zemax_blocks(text)
    if len(blocks) < 2:
        return f"line {last}: the file has no surface after surface {blocks[0][0]} (cut short?)" if blocks else None
    k, at, body = blocks[-1]
    heads = {w[0] for _, w in body}
    mid_line = not text.endswith(("\n", "\r"))  # a cut inside a line leaves no line end (whole files may end so)
    if (body[-1][0] if body else at) == last:  # the file ends inside the last surface's block
        common = set.intersection(*({w[0] for _, w in b} for _, _, b in blocks[:-1])) - OPTIONAL_SURFACE_COMMANDS
        missing = [h for h in ("DISZ", "DIAM") if h in common - heads] or sorted(common - heads)
        if missing:
            return (f"line {last}: the file ends inside surface {k}, which has no {', '.join(missing[:3])} line"
                    + ("s (every other surface has them)" if len(missing) > 1 else " (every other surface has one)")
                    + ": cut short?")
        words = body[-1][1] if body else []
        counts = [len(w) for _, _, b in blocks[:-1] for _, w in b if words and w[0] == words[0]]
        if mid_line and counts and len(words) < min(counts):
            return (f"line {last}: the file ends inside surface {k}'s {words[0]} line ({len(words)} fields, "
                    f"{min(counts)} on every other surface): cut short?")
        others = {w[0] for _, _, b in blocks for m, w in b if m != last} | {"SURF"}
        if mid_line and len(words) == 1 and words[0] not in others and any(h.startswith(words[0]) for h in others):
            return f"line {last}: the file ends inside a command ({words[0]!r}): cut short?"
    for n, words in body:
        if words[0] == "GLAS" and len(words) > 1 and words[1].upper() not in ("AIR", "MIRROR"):
            return (f"line {n}: the last surface ({k}) has glass {words[1]} after it, as a lens surface has: no "
                    "image surface (cut short, or written without one?)")
    for n, words in body:
        if words[0] == "DISZ" and len(words) > 1 and _number(words[1]) not in (None, 0.0):
            return (f"line {n}: the last surface ({k}) has a thickness ({words[1]}) after it, as a lens surface has: "
                    "no image surface (cut short, or written without one?)")
    return None


def _zemax_medium(words) -> tuple:
    """A Zemax ``GLAS`` line's medium, comparable: ("air",) for none (or a model glass of nd 1), ("n", nd, vd) for
    a model glass ``GLAS ___BLANK a b nd vd``, (NAME,) for a catalogue glass."""
    if not words or len(words) < 2 or words[1].upper() == "AIR":
        return ("air",)
    if words[1] == "___BLANK" and len(words) >= 5:
        nd, vd = _number(words[4]), _number(words[5]) if len(words) > 5 else 0.0
        return ("air",) if nd == 1.0 else ("n", nd, vd)
    return (words[1].upper(),)


def _zemax_index_mirrors(text: str, problems: list) -> tuple[str, list]:
    """The Zemax text with each mirror written as a medium of index -1 made a Zemax mirror, and those surfaces.

    Files converted from patents (Bill Claff's, OpticsDatabase's catadioptric lenses) write a mirror as refraction
    into n' = -1 (the paraxial sign convention of a reflection: n' = -n, Welford, Aberrations of Optical Systems,
    sec. 2.4) with no thickness after it, between surfaces of the same shape and no thickness that carry the medium
    in and out (``GLAS ___BLANK 1 0 -1``). rayoptics reads it as a medium of index -1 and the reader as air, so the
    mirror vanished (the Reflex-Nikkor 500 mm had EFL -224 mm; it is 500 mm with its mirrors). Here that surface
    is ``GLAS MIRROR`` (its medium after is the one before, as Zemax and rayoptics read a mirror), the surfaces of
    no thickness before it carry the medium the mirror sits in (the last one with a thickness), and those after
    it, at its place, must return to that medium: a Mangin's mirror inside its glass is one surface, the others
    dummies. Anything else of negative index is a problem (refused)."""
    blocks = _zemax_blocks(text)
    lines = text.splitlines()

    def find(body, head):
        return next(((n, w) for n, w in body if w[0] == head), (None, None))

    def thickness(j):
        return _number(find(blocks[j][2], "DISZ")[1][1]) if find(blocks[j][2], "DISZ")[1] else 0.0

    def curvature(j):
        words = find(blocks[j][2], "CURV")[1]
        return _number(words[1]) if words and len(words) > 1 else 0.0

    mirrors = []
    for j, (k, _, body) in enumerate(blocks):
        n_glas, glas = find(body, "GLAS")
        if not glas or glas[1:2] != ["___BLANK"] or len(glas) < 5 or (_number(glas[4]) or 0.0) >= 0.0:
            continue
        if _number(glas[4]) != -1.0 or thickness(j) != 0.0 or j in (0, len(blocks) - 1):
            problems.append(f"surface {k} (line {n_glas}): a medium of negative index (nd {glas[4]}, thickness "
                            f"{thickness(j):g}) that is not a mirror written as index -1 with no thickness after it")
            continue
        i = j - 1
        while i > 0 and thickness(i) == 0.0:
            i -= 1
        medium = find(blocks[i][2], "GLAS")[1]
        coincident = list(range(i + 1, j)) + [q for q in range(j + 1, len(blocks) - 1)
                                              if all(thickness(m) == 0.0 for m in range(j, q))]
        odd = [blocks[q][0] for q in coincident if curvature(q) != curvature(j)
               or (q > j and _zemax_medium(find(blocks[q][2], "GLAS")[1]) != _zemax_medium(medium))]
        if odd:
            problems.append(f"surface {k} (line {n_glas}): a mirror written as index -1 whose neighbours of no "
                            f"thickness (surface {odd[0]}) differ from it in shape or medium: not one mirror")
            continue
        indent = lines[n_glas - 1][:len(lines[n_glas - 1]) - len(lines[n_glas - 1].lstrip())]
        lines[n_glas - 1] = f"{indent}GLAS MIRROR 0 0 0 0"
        for p in range(i + 1, j):  # the surfaces before it, of no thickness: the medium it sits in
            n_p, _ = find(blocks[p][2], "GLAS")
            carried = f"{indent}{' '.join(medium)}" if _zemax_medium(medium) != ("air",) else ""
            if n_p is not None:
                lines[n_p - 1] = carried
            elif carried:
                lines[blocks[p][1] - 1] += "\n" + carried
        mirrors.append(k)
    return "\n".join(lines) + "\n", mirrors


def _number(word: str) -> float | None:
    """A file's finite number, or None."""
    try:
        value = float(word)
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def _surface_commands(fmt: str, text: str):
    """Each command of a lens file with the index of the surface it belongs to: ``(index or None, HEAD, words)``.

    CODE V: commands split on ``;``, ``SO`` is surface 0, each ``S`` the next surface (``Sk`` surface k), ``SI``
    ends the surfaces. Zemax: ``SURF k`` starts surface k. The surface-marker commands themselves are not
    yielded."""
    idx = None
    for line in text.splitlines():
        for cmd in (line.split(";") if fmt == "seq" else [line]):
            words = cmd.strip().split()
            if not words:
                continue
            head = words[0].upper()
            if fmt == "seq":
                if head == "SO":
                    idx = 0
                    continue
                if head == "S" or re.fullmatch(r"S\d+", head):
                    idx = (idx or 0) + 1 if head == "S" else int(head[1:])
                    continue
                if head == "SI":
                    idx = None
                    continue
            elif head == "SURF":
                idx = int(words[1]) if len(words) >= 2 and words[1].isdigit() else None
                continue
            yield idx, head, words


def _obstructions(fmt: str, text: str) -> dict:
    """{surface index: (kind, radius in file units)} for holes and obscurations rayoptics drops."""
    out = {}
    for idx, head, words in _surface_commands(fmt, text):
        if idx is None:
            continue
        if fmt == "seq" and head == "CIR":
            up = [w.upper() for w in words]
            kind = "hole" if "HOL" in up else "obscuration" if "OBS" in up else None
            if kind:
                try:
                    out[idx] = (kind, float(words[-1]))
                except ValueError:
                    pass
        elif fmt != "seq" and head in ("OBSC", "CLAP") and len(words) >= 3:
            try:
                lo, hi = float(words[1]), float(words[2])
            except ValueError:
                continue
            if head == "OBSC" and hi > 0:
                out[idx] = ("obscuration", hi)
            elif head == "CLAP" and lo > 0:
                out[idx] = ("hole", lo)
    return out


def _aperture_shapes(fmt: str, text: str) -> dict:
    """{surface index: {"offset": (dx, dy), "half_widths": (hx, hy) | None}} in file units, for clear apertures
    decentred from their surface's vertex (CODE V ``ADX`` / ``ADY``, Zemax ``OBDC``: an off-axis segment of a
    parent surface) or rectangular (CODE V ``REX`` / ``REY``, Zemax ``SQAP hx hy``), docs/optics.md."""
    out: dict = {}

    def number(words, k):
        try:
            return float(words[k])
        except (IndexError, ValueError):
            return None

    for idx, head, words in _surface_commands(fmt, text):
        if idx is None:
            continue
        shape = out.setdefault(idx, {"offset": (0.0, 0.0), "half_widths": None})
        dx, dy = shape["offset"]
        hx, hy = shape["half_widths"] or (None, None)
        if fmt == "seq" and head in ("ADX", "ADY", "REX", "REY"):
            value = number(words, 1)
            if value is None:
                continue
            if head == "ADX":
                dx = value
            elif head == "ADY":
                dy = value
            elif head == "REX":
                hx = abs(value)
            else:
                hy = abs(value)
        elif fmt != "seq" and head == "OBDC" and len(words) >= 3:
            dx, dy = number(words, 1) or 0.0, number(words, 2) or 0.0
        elif fmt != "seq" and head == "SQAP":
            hx, hy = number(words, 1), number(words, 2)
        shape["offset"] = (dx, dy)
        if hx is not None or hy is not None:
            shape["half_widths"] = (hx if hx is not None else hy, hy if hy is not None else hx)
    return {i: v for i, v in out.items() if v["offset"] != (0.0, 0.0) or v["half_widths"]}


def _set_aperture(s, shape: dict, scale: float, rot) -> None:
    """An off-axis or rectangular clear aperture of the file on surface ``s`` (its semi-diameter becomes the
    radius about the aperture's own centre: the rectangle's half-diagonal, or the file's circle)."""
    s.local_x = np.asarray(rot, float)[:, 0].copy()
    s.aperture_offset_mm = tuple(float(v) * scale for v in shape["offset"])
    if shape["half_widths"]:
        hx, hy = (float(v) * scale for v in shape["half_widths"])
        if hx > 0 and hy > 0:
            s.aperture_half_widths_mm = (hx, hy)
            s.semi_diameter_mm = math.hypot(hx, hy)
            s.semi_diameter_from_file = True


def _zemax_glass_numbers(fmt: str, text: str) -> dict:
    """{surface index: (nd, vd)} from Zemax ``GLAS NAME a b nd vd ...`` lines, which carry the glass's nd and vd
    whatever its name (vd 0: a constant index)."""
    if fmt != "zmx":
        return {}
    out = {}
    for idx, head, words in _surface_commands(fmt, text):
        if idx is None or head != "GLAS" or len(words) < 6:
            continue
        try:
            nd, vd = float(words[4]), float(words[5])
        except ValueError:
            continue
        if 1.0 < nd < 4.0 and 0.0 <= vd <= 150.0:
            out[idx] = (nd, vd)
    return out


def _coatings(fmt: str, text: str) -> dict:
    """{surface index: coating name} where the file names one (Zemax ``COAT NAME``)."""
    if fmt != "zmx":
        return {}
    return {idx: words[1] for idx, head, words in _surface_commands(fmt, text)
            if idx is not None and head == "COAT" and len(words) >= 2}


def _multiconfig(fmt: str, text: str) -> int:
    if fmt == "zmx":
        m = re.search(r"^\s*MNUM\s+(\d+)", text, re.M)
        return int(m.group(1)) if m else 1
    return 2 if re.search(r"^\s*ZOO\b", text, re.M | re.I) else 1


SMALLEST_RADIUS = 0.5  # file units: no lens file's surface has a radius this small (a curvature of 2 per unit)


def _radii_without_rdm(text: str) -> bool:
    """A CODE V file with neither ``RDM`` nor ``CUM`` whose surface values only make sense as radii.

    rayoptics reads such a file in curvature mode; a hand-written file (optiland's test files) means
    radii. Decided by physics: a curvature c with |c| EPD / 2 > 1 has no surface over the pupil; a file
    without EPD (its pupil given by FNO or NA) by a surface radius under :data:`SMALLEST_RADIUS` units."""
    if re.search(r"^\s*(RDM|CUM)\b", text, re.M | re.I):
        return False
    epd = re.search(r"^\s*EPD\s+([-+0-9.eE]+)", text, re.M | re.I)
    try:
        half = abs(float(epd.group(1))) / 2.0 if epd else SMALLEST_RADIUS
        values = [abs(float(m.group(1))) for m in re.finditer(r"^\s*S\s+([-+0-9.eE]+)", text, re.M)]
    except ValueError:
        return False
    return any(v * half > 1.0 for v in values)


def _zmx_for_rayoptics(text: str) -> bytes:
    """The Zemax text as UTF-8 for rayoptics' reader, with what it cannot read made explicit.

    rayoptics tries UTF-16 first, which decodes an even-length ASCII file without error as nonsense: it
    gets the text as decoded here (:func:`sniff_format`), in UTF-8. A ``DIAM`` line with the semi-diameter
    alone (hand-written files: rayoptics expects its type after it) gets type 1, a fixed semi-diameter, and a
    model glass ``GLAS ___BLANK a b nd`` without vd gets vd 0 (a constant index, as Zemax reads vd 0); a file
    without wavelengths (``WAVM`` / ``WAVL``) gets OpticStudio's default, 0.55 um."""
    lines = []
    if not re.search(r"^\s*(WAVM|WAVL)\b", text, re.M):
        lines.append("WAVM 1 0.55 1")
    for line in text.splitlines():
        words = line.split()
        if len(words) == 2 and words[0].upper() == "DIAM":
            line = line.rstrip() + " 1"
        elif len(words) == 5 and words[0].upper() == "GLAS" and words[1] == "___BLANK":
            line = line.rstrip() + " 0"  # a model glass given by nd alone: vd 0, a constant index (as Zemax reads it)
        lines.append(line)
    return ("\n".join(lines) + "\n").encode("utf-8")


def _extended_aspheres(fmt: str, text: str) -> dict:
    """{surface index: (type, normalising radius, {power: coefficient})} of the Zemax extended aspheres:
    ``XASPHERE`` (sum A_i rho^(2i), extra data ``XDAT 3`` = rho^2, ``XDAT 4`` = rho^4...) and ``XOSPHERE``
    (sum B_i rho^i, ``XDAT 3`` = rho^1...), rho = r / the normalising radius (``XDAT 2``). An ``XASPHERE``
    with ``PARM`` lines and no extra data (files converted from patents write them so) has the EVENASPH
    layout: ``PARM k`` the r^(2k) term. An ``ODDASPHE`` (Zemax's odd asphere) has ``PARM k`` the r^k term."""
    if fmt != "zmx":
        return {}
    kinds: dict = {}
    xdat: dict = {}
    parm: dict = {}
    for idx, head, words in _surface_commands(fmt, text):
        if idx is None:
            continue
        if head == "TYPE" and len(words) >= 2 and words[1].upper() in ("XASPHERE", "XOSPHERE", "ODDASPHE"):
            kinds[idx] = words[1].upper()
        elif head in ("XDAT", "PARM") and len(words) >= 3:
            try:
                k, v = int(words[1]), float(words[2])
            except ValueError:
                continue
            (xdat if head == "XDAT" else parm).setdefault(idx, {})[k] = v
    out = {}
    for idx, kind in kinds.items():
        x = xdat.get(idx, {}) if kind != "ODDASPHE" else {}
        norm = x.get(2, 1.0) or 1.0
        if kind == "ODDASPHE":
            terms = {k: v for k, v in parm.get(idx, {}).items() if k >= 1}
        elif x:
            n_terms = int(x.get(1, 0))
            step = 2 if kind == "XASPHERE" else 1
            terms = {step * (k - 2): v for k, v in x.items() if k >= 3 and (n_terms <= 0 or k - 2 <= n_terms)}
        elif kind == "XASPHERE":
            terms = {2 * k: v for k, v in parm.get(idx, {}).items() if k >= 1}
        else:
            terms = {}
        out[idx] = (kind, norm, {p: v for p, v in terms.items() if v != 0.0})
    return out


def _apply_extended_asphere(ifc, ext, where: str, problems: list, notes: list) -> None:
    """Turn an extended asphere into rayoptics' even asphere when its terms are all even powers from r^4 on,
    else into its radial polynomial (odd or r^2 terms: the scene's ``asphere`` with ``power_terms``); exact
    either way: a_p = coefficient / normalising radius^p."""
    from rayoptics.elem import profiles

    kind, norm, terms = ext
    prof = ifc.profile
    cv, cc = float(getattr(prof, "cv", 0.0) or 0.0), float(getattr(prof, "cc", 0.0) or 0.0)
    if any(p % 2 or p < 4 for p in terms):
        ifc.profile = profiles.RadialPolynomial(c=cv, cc=cc, coefs=[terms.get(p, 0.0) / norm ** p
                                                                    for p in range(1, max(terms) + 1)])
        ifc.z_type = kind
        if norm != 1.0:
            notes.append(f"{where}: {kind} read with its normalising radius {norm:g}")
        return
    top = max(terms, default=2)
    coefs = [terms.get(p, 0.0) / norm ** p for p in range(2, top + 1, 2)]
    ifc.profile = profiles.EvenPolynomial(c=cv, cc=cc, coefs=coefs or [0.0])
    ifc.z_type = "EVENASPH"
    if kind == "XOSPHERE" or norm != 1.0:
        notes.append(f"{where}: {kind} with even terms only read as an even asphere"
                     + (f" (normalising radius {norm:g})" if norm != 1.0 else ""))


def _fold_quadratic_term(ifc, where: str, problems: list, notes: list) -> None:
    """An r^2 polynomial term a_2 on a flat base is the paraboloid c = 2 a_2, k = -1, exactly: so rewritten, the
    paraxial data (rayoptics' come from the base curvature alone) see its power. On a curved base no conic is
    the same surface: a problem (the lens's first-order data would be wrong)."""
    from rayoptics.elem import profiles

    prof = getattr(ifc, "profile", None)
    kind = type(prof).__name__
    if kind not in ("EvenPolynomial", "RadialPolynomial"):
        return
    coefs = [float(c) for c in (getattr(prof, "coefs", None) or [])]
    at = 0 if kind == "EvenPolynomial" else 1  # the r^2 term's index (EvenPolynomial: r^2, r^4...; radial: r, r^2...)
    a2 = coefs[at] if len(coefs) > at else 0.0
    if a2 == 0.0:
        return
    cv = float(getattr(prof, "cv", 0.0) or 0.0)
    if cv != 0.0:
        problems.append(f"{where}: an r^2 term ({a2:g}) on a curved base (radius {1.0 / cv:g}): its paraxial power "
                        "is not representable, so the first-order data would be wrong")
        return
    coefs[at] = 0.0
    ifc.profile = getattr(profiles, kind)(c=2.0 * a2, cc=-1.0, coefs=coefs)
    notes.append(f"{where}: its r^2 term {a2:g} on a flat base read as the paraboloid it is (radius {0.5 / a2:g})")


CODEV_PROFILE_TYPES = {"SPH", "CON", "ASP", "XTO", "YTO", "SPS", "UDS", "AAC", "ZRN", "QCN", "QBF"}
CODEV_ASPHERE_TERMS = {"A", "B", "C", "D", "E", "F", "G", "H", "J"}


def _codev_profile_types(text: str) -> tuple[str, list]:
    """The CODE V text with the profile type made explicit where a surface gives conic or asphere terms (``K``,
    ``A``... ``J``) but no type command (optiland's ``asphere.seq``: rayoptics keeps such a surface spherical
    and fails on its first coefficient): ``ASP`` (an even asphere; ``CON`` for ``K`` alone) after the surface's
    ``S`` line. Returns (text, the surfaces so read)."""
    lines = text.splitlines()
    blocks: list = []  # [line index of the S command, surface number, {command heads}]
    idx = None
    for k, line in enumerate(lines):
        for cmd in line.split(";"):
            words = cmd.strip().split()
            if not words:
                continue
            head = words[0].upper()
            if head in ("SO", "SI") or head == "S" or re.fullmatch(r"S\d+", head):
                idx = None if head == "SI" else (0 if head == "SO" else (idx or 0) + 1 if head == "S" else int(head[1:]))
                if idx is not None:
                    blocks.append([k, idx, set()])
                continue
            if blocks and idx is not None:
                blocks[-1][2].add(head)
    fixed = []
    for k, idx, heads in reversed(blocks):
        if heads & CODEV_PROFILE_TYPES or not heads & (CODEV_ASPHERE_TERMS | {"K"}):
            continue
        lines.insert(k + 1, "ASP" if heads & CODEV_ASPHERE_TERMS else "CON")
        fixed.append(idx)
    return "\n".join(lines) + "\n", sorted(fixed)


def _open_rayoptics(path: Path, fmt: str, raw: bytes):
    """rayoptics' model of the file, read from a private copy (rayoptics may write a glass template
    beside the file it reads; ``optics info`` writes nothing where the user's file is)."""
    from rayoptics.codev import cmdproc
    from rayoptics.zemax import zmxread

    for module in (cmdproc, zmxread):  # their module-level log files (cv_cmd_proc.log...) in the working folder
        handler = getattr(module, "_fh", None)
        if handler is not None:
            module.logger.removeHandler(handler)
        module.logger.setLevel(logging.ERROR)

    with tempfile.TemporaryDirectory(prefix="straylight-lens-") as tmp:
        copy = Path(tmp) / ("lens." + fmt)
        atomicio.write_bytes(copy, raw)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                if fmt == "seq":
                    opm, info = cmdproc.read_lens(copy)
                else:
                    opm, info = zmxread.read_lens_file(copy, encoding="utf-8")
            except Exception as exc:  # noqa: BLE001 - any reader failure is one line naming the file
                raise _ReaderFailure(f"{path}: the {'CODE V' if fmt == 'seq' else 'Zemax'} reader could not "
                                      f"parse it ({type(exc).__name__}: {_first_line(exc)})") from None
    return opm, info


#: Zemax surface types whose whole shape rayoptics reads (or that are handled by kind: coordinate breaks,
#: paraxial lenses, gratings, toroids and extended polynomials get their own message)
ZEMAX_TYPES_READ = ("STANDARD", "EVENASPH", "COORDBRK", "PARAXIAL", "DGRATING", "TOROIDAL", "XOSPHERE", "XASPHERE",
                    "ODDASPHE")


def _profile(ifc, where: str, problems: list):
    """(type, radius in file units or None, conic, [A4, A6...] in file units, [(p, a_p)] further terms in file
    units: odd powers and r^2) of a surface profile."""
    prof = getattr(ifc, "profile", None)
    kind = type(prof).__name__ if prof is not None else type(ifc).__name__
    cv = float(getattr(prof, "cv", 0.0) or 0.0)
    radius = None if cv == 0.0 else 1.0 / cv
    z_type = getattr(ifc, "z_type", None)
    base: tuple = ("plane" if radius is None else "sphere"), radius, float(getattr(prof, "cc", 0.0) or 0.0), [], []
    if z_type is not None and z_type not in ZEMAX_TYPES_READ:
        # rayoptics keeps the base sphere/conic of a Zemax type it does not know (QED_TYPE, ODDASPHE, SZERNSAG...)
        # and drops the rest of its shape without a word
        problems.append(f"{where}: surface type {z_type} is not supported (sphere, conic, even or odd asphere)")
        return base
    if kind == "Spherical":
        return ("plane" if radius is None else "sphere"), radius, 0.0, [], []
    if kind == "Conic":
        cc = float(getattr(prof, "cc"))
        if radius is None:  # a flat surface is a plane whatever its conic constant (c = 0: no sag)
            return "plane", None, 0.0, [], []
        return ("conic" if cc != 0 else "sphere"), radius, cc, [], []
    if kind in ("EvenPolynomial", "RadialPolynomial"):
        raw = [float(c) for c in (getattr(prof, "coefs", None) or [])]
        # by power: EvenPolynomial's coefs are r^2, r^4...; RadialPolynomial's r^1, r^2, r^3...
        by_power = {(2 * (k + 1) if kind == "EvenPolynomial" else k + 1): c for k, c in enumerate(raw) if c != 0.0}
        top = max((p for p in by_power if p >= 4 and p % 2 == 0), default=2)
        coefs = [by_power.get(p, 0.0) for p in range(4, top + 1, 2)]
        terms = sorted((p, c) for p, c in by_power.items() if p % 2 or p < 4)
        cc = float(getattr(prof, "cc", 0.0))
        if not coefs and not terms:
            if radius is None:  # flat, no terms: a plane whatever its conic constant
                return "plane", None, 0.0, [], []
            return ("conic" if cc else "sphere"), radius, cc, [], []
        return "asphere", radius, cc, coefs, terms
    problems.append(f"{where}: surface type {getattr(ifc, 'z_type', kind)} ({kind}) is not supported "
                    "(sphere, conic, even or odd asphere)")
    return base


CATALOGUES = ("Schott", "Ohara", "Hoya", "CDGM", "Sumita")


def _catalogue_glass(name: str):
    """A catalogue glass for a name rayoptics did not find, or None. rayoptics' CODE V reader turns
    ``N-SK16_SCHOTT`` into ``N--SK16`` (it expects ``NSK16_SCHOTT``): the doubled hyphen is undone and the
    name looked up in each catalogue."""
    from opticalglass import glassfactory

    for cand in dict.fromkeys((name, name.replace("--", "-"), name.upper().replace("--", "-"))):
        for cat in CATALOGUES:
            try:
                return glassfactory.create_glass(cand, cat)
            except Exception:  # noqa: BLE001 - opticalglass raises its own GlassNotFoundError per catalogue
                continue
    return None


MODEL_GLASS = re.compile(r"\s*(1\.\d+)\s*:\s*(\d+(?:\.\d+)?)\s*")  # nd:vd, e.g. 1.5168:64.17
GLASS_CODE = re.compile(r"\s*(\d{3})(\d{3})(?:\.\d*)?\s*")  # the six-digit code, e.g. 517642 (nd 1.517, vd 64.2)


def _model_glass(name: str):
    """A glass given by its numbers rather than a catalogue name: ``nd:vd`` (``1.5168:64.17``) or the
    six-digit glass code (``517642``: nd = 1.517, vd = 64.2), as opticalglass' ModelGlass (the model rayoptics
    uses for Zemax model glasses); None for a name."""
    from opticalglass.modelglass import ModelGlass

    m = MODEL_GLASS.fullmatch(name)
    if m:
        nd, vd = float(m.group(1)), float(m.group(2))
    else:
        m = GLASS_CODE.fullmatch(name)
        if not m:
            return None
        nd, vd = 1.0 + int(m.group(1)) / 1000.0, int(m.group(2)) / 10.0
    if not (1.0 < nd < 4.0 and 5.0 <= vd <= 120.0):
        return None
    return ModelGlass(nd, vd, name.strip())


def _substitutions(info) -> list[str]:
    """One note per glass name rayoptics replaced by a similar catalogue glass (Ohara's L-BAL35 read as
    S-BAL35; Schott's old BK7 as the Buchdahl model of Robb's 1983 catalogue): its reader's map
    {name in the file: (glass used, catalogue)}."""
    subs = info[1] if isinstance(info, tuple) and len(info) > 1 and isinstance(info[1], dict) else {}
    notes = []
    for name, used in subs.items():
        glass, cat = (tuple(used) + ("", ""))[:2] if isinstance(used, (tuple, list)) else (str(used), "")
        notes.append(f"glass {name} is not in the catalogues as written; rayoptics substituted {glass}"
                     + (f" ({cat})" if cat else ""))
    return notes


def _glass_name(medium) -> str | None:
    name = medium.name() if hasattr(medium, "name") else str(medium)
    if name.lower() in ("air", ""):
        return None
    return name


def _float_by_stop_size(opm, path: Path, why: str = "aperture floats by stop size (FLOA)") -> str:
    """Zemax ``FLOA`` (aperture "float by stop size"): the entrance pupil is whatever the stop's semi-diameter
    lets through. rayoptics ignores the command and keeps its default 1-unit pupil: the pupil diameter is
    scaled so that the paraxial marginal ray fills the stop (its height is linear in the pupil's). Returns the
    note to warn with."""
    sm = opm["seq_model"]
    stop = sm.stop_surface
    ifc = sm.ifcs[stop] if stop is not None and 0 < stop < len(sm.ifcs) - 1 else None
    if ifc is None or not getattr(ifc, "clear_apertures", None):
        return f"{why} but the file gives the stop no semi-diameter: pupil as read"
    sd = float(ifc.surface_od())
    pupil = opm["optical_spec"]["pupil"]
    y = abs(float(opm["analysis_results"]["parax_data"].ax_ray[stop][0]))
    epd = 2.0 * float(opm["analysis_results"]["parax_data"].fod.enp_radius)
    if not (sd > 0 and y > 0 and math.isfinite(y) and epd > 0):
        return f"{why} but no paraxial ray reaches the stop: pupil as read"
    pupil.key = ("object", "epd")
    pupil.value = epd * sd / y
    _rayoptics_update(opm, path)
    return f"{why}: entrance pupil {pupil.value:.6g} file units, the stop's semi-diameter {sd:g}"


def _ends_inside_the_lens(surfaces: list, image_gap_mm: float, efl_mm: float, bfl_mm: float,
                          afocal: bool) -> str | None:
    """Why the file's image surface cannot be the lens's image (the file stops inside the lens: five of
    OpticsDatabase's catadioptric lenses end so), or None: the image lies inside glass; or the image surface sits
    on a curved last surface, no distance between, while the lens as written focuses elsewhere (by more than 1 %
    of its focal length). Neither is so on any lens of the corpus or the sweep that images (docs/optics.md): a
    sensor's cover glass puts the image on a flat surface, and teleconverters focus nowhere near theirs."""
    last = surfaces[-1] if surfaces else None
    if last is None:
        return None
    if abs(last.n - 1.0) > 1e-6 and not last.mirror:
        return (f"the image lies inside glass (n {last.n:.5g} after surface {last.index}): the file "
                "ends inside the lens (incomplete?)")
    curved = last.radius_mm is not None or last.mirror
    if image_gap_mm == 0.0 and curved and not afocal and abs(bfl_mm) > 0.01 * abs(efl_mm):
        what = "mirror" if last.mirror else f"R {last.radius_mm:.6g} mm"
        return (f"the image surface is on surface {last.index} ({what}, no distance between) but the lens as written "
                f"focuses {bfl_mm:.4g} mm from it (EFL {efl_mm:.4g} mm): the file ends before the lens does "
                "(incomplete?)")
    return None


def _set_wavelength(opm, wavelength_nm: float, path: Path) -> None:
    osp = opm["optical_spec"]
    osp["wvls"].set_from_list([[float(wavelength_nm), 1.0]])
    osp["wvls"].reference_wvl = 0
    _rayoptics_update(opm, path)


def read_prescription(path, wavelength_nm: float | None = None, glass: dict | None = None,
                      force: bool = False) -> Prescription:
    """The lens file at ``path`` as a :class:`Prescription` in the scene frame.

    ``glass``: {NAME: n} for glasses the catalogues lack. Raises :class:`OpticsFileError` (one line) for a
    file that is not a lens file, an unknown glass, a finite object distance, or (without ``force``) a
    surface type that has no exact part.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise OpticsFileError(f"{path}: cannot read ({exc.strerror or exc})") from None
    fmt, text = sniff_format(raw, path)
    cut = _zemax_truncation(text) if fmt == "zmx" else None
    if cut:
        raise OpticsFileError(f"{path}: {cut}")
    try:
        return _read_prescription(path, raw, fmt, text, [], wavelength_nm, glass, force)
    except _ReaderFailure:
        # rayoptics finds the object-side angles of real-image-height fields (Zemax FTYP 3) by a wide-angle
        # search of the real entrance pupil, which fails on some wide-angle lenses: read them again as
        # paraxial image heights (FTYP 2), which only sizes the detector and the field angles
        if fmt != "zmx" or not re.search(r"^\s*FTYP\s+3\b", text, re.M):
            raise
        paraxial = re.sub(r"^(\s*FTYP\s+)3\b", r"\g<1>2", text, count=1, flags=re.M)
        try:
            return _read_prescription(path, raw, fmt, paraxial, [
                "rayoptics could not aim real rays at the file's real-image-height fields (FTYP 3): fields read as "
                "paraxial image heights"], wavelength_nm, glass, force)
        except _ReaderFailure:
            pass
        raise


def _read_prescription(path: Path, raw: bytes, fmt: str, text: str, notes: list, wavelength_nm, glass,
                       force: bool) -> Prescription:
    """:func:`read_prescription` of the file's decoded ``text`` (``raw`` its bytes, for CODE V)."""
    if fmt == "seq" and _radii_without_rdm(text):
        raw = b"RDM\n" + raw
        text = "RDM\n" + text
        notes.append("no RDM/CUM in the file and its S values as curvatures would give radii smaller than the "
                     "entrance pupil: read as radii (RDM)")
    if fmt == "seq":
        typed, fixed = _codev_profile_types(text)
        if fixed:
            raw, text = typed.encode("utf-8"), typed
            notes.append(f"surface(s) {', '.join(map(str, fixed))}: conic or asphere terms without a profile type: read "
                         "as an even asphere (ASP; CON for K alone)")
    if fmt == "zmx":
        bad: list = []
        text, mirrors = _zemax_index_mirrors(text, bad)
        if bad:
            raise OpticsFileError(f"{path}: {bad[0]}")
        if mirrors:
            notes.append(f"surface(s) {', '.join(map(str, mirrors))}: a medium of index -1 with no thickness, the sign "
                         "convention of a reflection, read as a mirror (Zemax MIRROR) in the medium it sits in")
    opm, info = _open_rayoptics(path, fmt, _zmx_for_rayoptics(text) if fmt == "zmx" else raw)
    glass = dict(glass or {})
    sm = opm["seq_model"]
    # glasses the catalogues lack: --glass NAME=N, or refused naming them
    from opticalglass.opticalmedium import ConstantIndex

    missing = []
    file_numbers = _zemax_glass_numbers(fmt, text)
    for gi, gap in enumerate(sm.gaps):
        nm = gap.medium.name() if hasattr(gap.medium, "name") else ""
        if isinstance(gap.medium, ConstantIndex) and nm.startswith("not "):
            gname = nm[4:]
            match = next((k for k in glass if k.upper() == gname.upper()), None)
            model = None if match is not None else _model_glass(gname)
            found = None if match is not None or model is not None else _catalogue_glass(gname)
            other = None if match is not None or model is not None or found is not None else other_medium(gname)
            if other is not None:
                gap.medium = other
                note = f"glass {gname} read as {other.catalog_name()}"
                if note not in notes:
                    notes.append(note)
            elif model is not None:
                gap.medium = model
                note = (f"glass {gname} read as a model glass nd {model.n:g}, vd {model.v:g} (opticalglass' ModelGlass, "
                        "as rayoptics reads Zemax model glasses)")
                if note not in notes:
                    notes.append(note)
            elif found is not None:
                gap.medium = found
                note = f"glass {gname} read as {found.name()} ({found.catalog_name()})"
                if note not in notes:
                    notes.append(note)
            elif match is None and gi in file_numbers:
                from opticalglass.modelglass import ModelGlass

                nd, vd = file_numbers[gi]
                gap.medium = ModelGlass(nd, vd, gname) if vd > 0 else ConstantIndex(nd, gname)
                note = (f"glass {gname} is not in the catalogues: read from the file's own nd {nd:g}, vd {vd:g}"
                        + (" (opticalglass' ModelGlass)" if vd > 0 else " (a constant index)"))
                if note not in notes:
                    notes.append(note)
            elif match is None:
                missing.append(gname)
            else:
                gap.medium = ConstantIndex(float(glass[match]), gname)
    if missing:
        raise OpticsFileError(f"{path}: unknown glass {', '.join(sorted(set(missing)))} (not in the Schott, Ohara, "
                              f"Hoya, CDGM, Sumita catalogues nor docs/optics.md's other materials); give its index "
                              f"with --glass {missing[0]}=N")
    subs = (info[0] if isinstance(info, tuple) else {}).get("glass substituted", 0) if isinstance(info, tuple) else 0
    if subs:
        named = _substitutions(info)
        notes.extend(named or [f"{subs} glass name(s) not found as written; rayoptics substituted the closest "
                               "catalogue glass"])
    units = str(opm["system_spec"].dimensions)
    scale = UNIT_MM.get(units.lower())
    if scale is None:
        raise OpticsFileError(f"{path}: unknown length unit {units!r}")
    osp = opm["optical_spec"]
    ref_wvl = float(osp["wvls"].central_wvl)
    wvl = float(wavelength_nm) if wavelength_nm else ref_wvl
    _set_wavelength(opm, wvl, path)
    sm = opm["seq_model"]
    problems: list = []
    for i, ext in _extended_aspheres(fmt, text).items():
        if 0 < i < len(sm.ifcs) - 1:
            _apply_extended_asphere(sm.ifcs[i], ext, f"surface {i}", problems, notes)
    for i in range(1, len(sm.ifcs) - 1):
        _fold_quadratic_term(sm.ifcs[i], f"surface {i}", problems, notes)
    pupil = opm["optical_spec"]["pupil"]
    if fmt == "zmx" and re.search(r"^\s*FLOA\b", text, re.M):
        notes.append(_float_by_stop_size(opm, path))
    elif (fmt == "zmx" and not re.search(r"^\s*(ENPD|FNUM|OBNA)\b", text, re.M)
          and tuple(pupil.key) == ("object", "epd") and float(pupil.value) == 1.0):
        # no aperture command at all (hand-edited files): rayoptics' 1-unit pupil is no aperture of the lens's;
        # the stop's semi-diameter sets it, as FLOA (7 OpticsDatabase camera lenses: their marked f-numbers)
        notes.append("the file gives no aperture (ENPD, FNUM, OBNA or FLOA): "
                     + _float_by_stop_size(opm, path, "the stop's size sets it, as FLOA"))
    else:
        _rayoptics_update(opm, path)
    obj_dist = float(sm.gaps[0].thi) * scale
    if abs(obj_dist) < 1e8 and not math.isinf(obj_dist):
        raise OpticsFileError(f"{path}: object at a finite distance ({obj_dist:g} mm); optics import models an "
                              "object at infinity (a collimated source)")
    nconf = _multiconfig(fmt, text)
    if nconf > 1:
        notes.append(f"multi-configuration file ({nconf} configurations): configuration 1 imported")
    obstr = _obstructions(fmt, text)
    coats = _coatings(fmt, text)
    apertures = _aperture_shapes(fmt, text)

    n_ifc = len(sm.ifcs)
    tfrms = sm.gbl_tfrms
    rndx = [float(r[0]) for r in sm.rndx]
    surfaces = []
    stop_idx = sm.stop_surface
    # clear apertures where the file gives none: the marginal ray at the field's edge (rayoptics' boundary rays)
    given = {i: bool(getattr(ifc, "clear_apertures", None) or getattr(ifc, "edge_apertures", None))
             for i, ifc in enumerate(sm.ifcs)}
    given_sd = {i: float(sm.ifcs[i].surface_od()) for i in given if given[i]}
    try:
        with np.errstate(all="ignore"):  # rayoptics' boundary rays that miss a surface come back NaN, not as warnings
            sm.set_clear_apertures()
        traced_sd = {i: float(ifc.max_aperture) for i, ifc in enumerate(sm.ifcs)}
    except Exception:  # noqa: BLE001 - fall back to the paraxial marginal + chief ray heights
        try:
            sm.set_clear_apertures_paraxial()
        except Exception as exc:  # noqa: BLE001 - no paraxial solution either: a truncated or incomplete file
            raise OpticsFileError(f"{path}: no ray passes the system (neither a real nor a paraxial trace; is the "
                                  f"file complete, with an image surface?): {type(exc).__name__}") from None
        traced_sd = {i: float(ifc.max_aperture) for i, ifc in enumerate(sm.ifcs)}
    for i, sd in given_sd.items():
        sm.ifcs[i].set_max_aperture(sd)
    names: dict[str, list] = {}  # label -> its surfaces
    for i in range(1, n_ifc - 1):
        ifc = sm.ifcs[i]
        where = f"surface {i}"
        kind, radius, cc, coefs, terms = _profile(ifc, where, problems)
        rot, trans = tfrms[i]
        rot = np.asarray(rot, float)
        mirror = getattr(ifc, "interact_mode", "") == "reflect"
        z_in = sm.z_dir[i - 1]
        travel = z_in * rot[:, 2]
        n_before = abs(rndx[i - 1])
        n_after = abs(rndx[i]) if i < len(rndx) else 1.0
        medium_after = sm.gaps[i].medium if i < len(sm.gaps) else None
        gname = _glass_name(medium_after) if medium_after is not None else None
        if getattr(ifc, "phase_element", None) is not None:
            problems.append(f"{where}: diffractive surface (grating or DOE) is not supported")
        label = (getattr(ifc, "label", "") or "").strip()
        if given.get(i):
            sd, from_file = given_sd[i], True
        else:
            sd, from_file = traced_sd.get(i, 1.0) * 1.05, False
        if not (sd > 0 and math.isfinite(sd)):
            sd, from_file = 1.0, False
        scale_c = [c / scale ** (2 * k + 3) for k, c in enumerate(coefs)]  # A_(2k+4) in mm^-(2k+3)
        s = OpticalSurface(
            index=i, name=f"s{i}", type=kind,
            radius_mm=None if radius is None else radius * scale, conic=cc, coefficients=scale_c,
            thickness_mm=float(sm.gaps[i].thi) * scale if i < len(sm.gaps) else 0.0,
            glass=gname if (n_after != 1.0 or gname) and not (gname or "").lower().startswith("air") else None,
            n=n_after, n_before=n_before, mirror=mirror,
            semi_diameter_mm=sd * scale, semi_diameter_from_file=from_file,
            vertex_mm=np.asarray(trans, float) * scale, local_z=rot[:, 2].copy(), travel_in=travel,
            stop=(i == stop_idx), coating=coats.get(i),
            dummy=(not mirror and abs(n_after - n_before) < 1e-12),
            power_terms=[(p, c / scale ** (p - 1)) for p, c in terms],  # a_p in mm^(1-p)
        )
        if i in obstr:
            s.inner_kind, r_in = obstr[i]
            s.inner_radius_mm = r_in * scale
        if i in apertures:
            _set_aperture(s, apertures[i], scale, rot)
        if label:
            names.setdefault(label, []).append(s)
        surfaces.append(s)
    for s in surfaces:  # a semi-diameter past where the conic has a sag (a fisheye's front meniscus: DIAM 16.21
        # on R 15.9) has no surface there: the aperture ends just inside the rim of the hemisphere
        if s.radius_mm is not None and 1.0 + s.conic > 0:
            rim = abs(s.radius_mm) / math.sqrt(1.0 + s.conic)
            if s.semi_diameter_mm > 0.999 * rim:
                notes.append(f"s{s.index}: semi-diameter {s.semi_diameter_mm:g} mm reaches past the surface's rim "
                             f"(radius {s.radius_mm:g} mm, conic {s.conic:g}): clear aperture {0.999 * rim:.6g} mm")
                s.semi_diameter_mm = 0.999 * rim
        if s.coefficients or s.power_terms:  # terms that give no lens surface over the aperture (the Sigma 14-24 mm files' extended
            # aspheres, read as Zemax defines XASPHERE: 1e22 mm of sag at 19 mm; real aspheres stay under 1 x it)
            h = sag_mm(s, s.semi_diameter_mm)
            if not (math.isfinite(h) and abs(h) <= 2.0 * s.semi_diameter_mm):
                problems.append(f"surface {s.index}: the asphere's terms give a sag of {h:.3g} mm at its semi-diameter "
                                f"{s.semi_diameter_mm:g} mm: not a lens surface (the file's coefficients are not those "
                                "of its surface type?)")
                s.coefficients, s.power_terms = [], []
                s.type = "plane" if s.radius_mm is None else ("conic" if s.conic else "sphere")
    for label, group in names.items():
        if len(group) == 1 and re.fullmatch(r"[A-Za-z0-9_.\-]+", label) and label.lower() not in ("obj", "img"):
            group[0].name = label
    if problems and not force:
        raise OpticsFileError(f"{path}: {problems[0]}" + (f" (and {len(problems) - 1} more)" if len(problems) > 1
                                                          else "") + "; --force imports it approximated")
    notes += [p + ": imported as its base sphere/conic (--force)" for p in problems]

    img_rot, img_t = tfrms[n_ifc - 1]
    img_rot = np.asarray(img_rot, float)
    fod = opm["analysis_results"]["parax_data"].fod
    fov = osp["fov"]
    fields = [float(f.y) for f in fov.fields]
    efl = float(fod.efl) * scale
    afocal = not (math.isfinite(efl) and 1e-9 < abs(efl) < 1e12)
    incomplete = _ends_inside_the_lens(surfaces, float(sm.gaps[n_ifc - 2].thi) * scale, efl,
                                       float(fod.bfl) * scale, afocal)
    if incomplete:
        raise OpticsFileError(f"{path}: {incomplete}")
    if afocal:
        notes.append("afocal as read (no finite focal length): efl, bfl and f/# are null")
    if fov.key[1] == "angle":
        fields_deg = fields
    else:
        fields_deg = [0.0 if afocal else math.degrees(math.atan2(y * scale, abs(efl))) for y in fields]
    stop_sd = None
    if stop_idx is not None and 0 < stop_idx < n_ifc - 1:
        stop_sd = float(sm.ifcs[stop_idx].surface_od()) * scale
    return Prescription(
        file=path.name, format="CODE V" if fmt == "seq" else "Zemax", units_in_file=units, wavelength_nm=wvl,
        efl_mm=math.nan if afocal else efl, bfl_mm=math.nan if afocal else float(fod.bfl) * scale,
        fno=math.nan if afocal else float(fod.fno), epd_mm=2.0 * float(fod.enp_radius) * scale,
        fields_deg=[abs(f) for f in fields_deg], surfaces=surfaces,
        image_vertex_mm=np.asarray(img_t, float) * scale, image_local_z=img_rot[:, 2].copy(),
        image_travel_in=sm.z_dir[n_ifc - 2] * img_rot[:, 2], stop_semi_diameter_mm=stop_sd, warnings=notes,
        model=opm, scale=scale)
