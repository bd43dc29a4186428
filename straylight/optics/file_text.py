"""What a lens file's text says, read beside rayoptics' model of it (straylight.optics.reader).

rayoptics parses the file; this module reads what its model does not keep or gets wrong, from the text:
a Zemax file cut short (:func:`zemax_truncation`), mirrors written as a medium of index -1
(:func:`zemax_index_mirrors`), obstructions and holes (CODE V ``CIR ... OBS`` / ``HOL``, Zemax ``OBSC`` /
annular ``CLAP``), rectangular and decentred apertures, coatings, multi-configurations, the ``GLAS`` line's
nd / vd, extended aspheres' terms, and the rewrites rayoptics' readers need (docs/optics.md, "Readers'
quirks handled").
"""
from __future__ import annotations

import math
import re



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


def zemax_truncation(text: str) -> str | None:
    """Where a Zemax file stops inside its surface list (a download cut short, a converter that stopped), as
    ``"line N: ..."``; None for a whole file. Signs, each absent from every whole file of the corpus (1218
    OpticsDatabase files, docs/optics.md): the text ends inside a character (UTF-16 cut at an odd byte); the file
    ends inside its last surface's block and that block lacks a command every other surface has, or its last line
    has fewer fields than that command has on every other surface, or is a lone fragment of a command name; the
    last surface (the image) has a glass or a thickness after it, as a lens surface has (a glass that is the one
    before it is an immersed image, not a lens surface: a microscope objective's into water)."""
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
    before = next((w for _, w in blocks[-2][2] if w[0] == "GLAS"), None)
    for n, words in body:
        if words[0] == "GLAS" and len(words) > 1 and words[1].upper() not in ("AIR", "MIRROR"):
            if before is not None and _zemax_medium(words) == _zemax_medium(before):
                break  # the medium before it goes on to the image (an immersed image): no lens surface
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


def zemax_coordinate_break_media(text: str) -> tuple[str, list]:
    """The Zemax text with each coordinate break that has no ``GLAS`` line given the medium it sits in, and those
    surfaces. A coordinate break bends no ray and has no material of its own: Zemax keeps the medium in effect
    before it (the ray inside a prism stays in its glass across the break that tilts the next face); rayoptics
    read the space after one as air (ZOSPy's TIR prism: its BK7 ended at the break before the reflecting face,
    which became a glass-air surface, and the import gave the prism EFL -159 mm). The medium in effect after a
    surface is its glass, the one before it for a mirror or a coordinate break, else air."""
    blocks = _zemax_blocks(text)
    lines = text.splitlines(keepends=True)
    eol = next((ln[len(ln.rstrip("\r\n")):] for ln in lines if ln.rstrip("\r\n") != ln), "\n")
    inserts: dict = {}  # line number after which to insert -> the GLAS line
    changed = []
    medium = None  # words of the GLAS line in effect (None: air)
    for k, at, body in blocks:
        kind = next((w[1].upper() for _, w in body if w[0] == "TYPE" and len(w) > 1), "STANDARD")
        glas = next((w for _, w in body if w[0] == "GLAS" and len(w) > 1), None)
        if kind == "COORDBRK" and glas is None:
            if medium is not None:
                row = next((m for m, w in body if w[0] == "TYPE"), at)
                indent = lines[row - 1][:len(lines[row - 1]) - len(lines[row - 1].lstrip())] or "  "
                inserts[row] = indent + " ".join(medium) + eol
                changed.append(k)
            continue
        if glas is not None and glas[1].upper() == "MIRROR":
            continue
        medium = None if glas is None or glas[1].upper() == "AIR" else glas
    if not inserts:
        return text, []
    out = []
    for n, line in enumerate(lines, start=1):
        out.append(line)
        if n in inserts:
            out.append(inserts[n])
    return "".join(out), changed


def zemax_index_mirrors(text: str, problems: list) -> tuple[str, list]:
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


#: Zemax commands whose first argument is a number (``DISZ INFINITY`` is the one word allowed)
ZEMAX_NUMERIC = frozenset({"CURV", "DISZ", "DIAM", "CONI", "PARM", "XDAT", "ENPD", "FNUM", "OBNA", "FLOA", "MEMA",
                           "SQAP", "CLAP", "OBSC", "FLAP", "DECX", "DECY", "TILT", "THIC"})


def zemax_bad_number(text: str) -> str | None:
    """Where a Zemax file has a word for a number (for the reader's one-line refusal: ``line 19: DISZ 'abc' is not
    a number``), or None."""
    for n, line in enumerate(text.splitlines(), start=1):
        words = line.split()
        if len(words) > 2 and words[0].upper() == "GLAS":  # the name, then numbers (nd, vd...)
            word = next((w for w in words[2:] if _number(w) is None and w.upper() not in ("NAN", "INF")), None)
            if word is not None:
                return f"line {n}: GLAS {words[1]} has {word!r} for a number"
            continue
        if len(words) < 2 or words[0].upper() not in ZEMAX_NUMERIC:
            continue
        head, first = words[0].upper(), words[1]
        if head == "DISZ" and first.upper() in ("INFINITY", "INF"):
            continue
        try:
            float(first)
        except ValueError:
            return f"line {n}: {head} {first!r} is not a number"
    return None


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


def zemax_stop(fmt: str, text: str) -> int | None:
    """The Zemax surface whose block marks ``STOP`` (None: none, or a CODE V file). rayoptics' reader drops a
    stop on surface 1 (it sets a stop only once three surfaces are read): the common layout of a stop in
    front of the lens."""
    if fmt != "zmx":
        return None
    return next((idx for idx, head, _ in _surface_commands(fmt, text) if head == "STOP" and idx is not None), None)


def zemax_comments(fmt: str, text: str) -> dict:
    """Zemax ``COMM`` per surface index (a part is named after its surface's comment where unique: CONTRACTS 8.1;
    CODE V's ``SLB`` labels come through rayoptics)."""
    out: dict = {}
    if fmt != "zmx":
        return out
    for idx, head, words in _surface_commands(fmt, text):
        if head == "COMM" and idx is not None and len(words) > 1:
            out[idx] = " ".join(words[1:]).strip().strip('"').strip()
    return out


def obstructions(fmt: str, text: str) -> dict:
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


def aperture_shapes(fmt: str, text: str) -> dict:
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


def zemax_glass_numbers(fmt: str, text: str) -> dict:
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


def coatings(fmt: str, text: str) -> dict:
    """{surface index: coating name} where the file names one (Zemax ``COAT NAME``)."""
    if fmt != "zmx":
        return {}
    return {idx: words[1] for idx, head, words in _surface_commands(fmt, text)
            if idx is not None and head == "COAT" and len(words) >= 2}


def multiconfig(fmt: str, text: str) -> int:
    if fmt == "zmx":
        m = re.search(r"^\s*MNUM\s+(\d+)", text, re.M)
        return int(m.group(1)) if m else 1
    m = re.search(r"^\s*ZOO\s+(\d+)", text, re.M | re.I)  # CODE V "ZOO 5": five zoom positions
    return int(m.group(1)) if m else 2 if re.search(r"^\s*ZOO\b", text, re.M | re.I) else 1


def zemax_config_object_distance(fmt: str, text: str, config: int = 1) -> float | None:
    """The object distance a Zemax multi-configuration file gives configuration ``config`` (its ``THIC 0 <config>
    <value>`` operand: a macro lens's magnifications), None where it gives none or it is infinite. The surface
    data hold one state; a macro lens's may keep the object at infinity while every configuration sets it near."""
    if fmt != "zmx":
        return None
    for line in text.splitlines():
        words = line.split()
        if len(words) >= 4 and words[0].upper() == "THIC" and words[1] == "0" and words[2] == str(int(config)):
            value = _number(words[3])
            return value if value is not None and abs(value) < 1e10 else None
    return None


def codev_without_titles(text: str) -> tuple[str, int]:
    """The CODE V text without its title lines (``TIT``/``TITLE``, and a zoom's ``ZOO TIT``), and how many went.
    rayoptics reads a title that starts with a zoom position's name (opticspy's XF_HW3_PB2.seq: ``TITLE 'Z1
    decenter 0'``, ``TIT Z1 "..."``) as a zoom qualifier and fails (IndexError); the import needs no title."""
    kept, dropped = [], 0
    for line in text.splitlines(keepends=True):
        words = line.replace(";", " ").split()
        head = words[0].upper() if words else ""
        if head in ("TIT", "TITLE") or (head == "ZOO" and len(words) > 1 and words[1].upper() in ("TIT", "TITLE")):
            dropped += 1
            continue
        kept.append(line)
    return "".join(kept), dropped


def codev_unknown_catalogs(text: str, known: set) -> tuple[str, dict]:
    """A CODE V file with each surface's glass ``NAME_CATALOG`` whose catalogue is not in ``known`` (upper case)
    written as ``NAME`` (rayoptics' reader stops at an unknown catalogue: optiland's telescope_objective.seq,
    ``CAF2_DAIMON-20``), and {NAME: NAME_CATALOG} of those renamed."""
    renamed: dict = {}
    out = []
    for line in text.splitlines():
        cmds = line.split(";")
        for k, cmd in enumerate(cmds):
            words = cmd.split()
            if len(words) >= 4 and re.fullmatch(r"S\d*|SO|SI", words[0].upper()) and "_" in words[3]:
                name, _, catalog = words[3].rpartition("_")
                if name and catalog.upper() not in known:
                    renamed[name] = words[3]
                    cmds[k] = re.sub(rf"(?<!\S){re.escape(words[3])}(?!\S)", name, cmd, count=1)
        out.append(";".join(cmds))
    return "\n".join(out) + ("\n" if text.endswith("\n") else ""), renamed


SMALLEST_RADIUS = 0.5  # file units: no lens file's surface has a radius this small (a curvature of 2 per unit)


def radii_without_rdm(text: str) -> bool:
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


def zmx_for_rayoptics(text: str) -> bytes:
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


def extended_aspheres(fmt: str, text: str) -> dict:
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


CODEV_PROFILE_TYPES = {"SPH", "CON", "ASP", "XTO", "YTO", "SPS", "UDS", "AAC", "ZRN", "QCN", "QBF"}


CODEV_ASPHERE_TERMS = {"A", "B", "C", "D", "E", "F", "G", "H", "J"}


def codev_profile_types(text: str) -> tuple[str, list]:
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
