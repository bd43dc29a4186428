"""Read a lens-design file (CODE V ``.seq``, Zemax ``.zmx``) into a list of surfaces in the scene frame.

The parsing is rayoptics' (BSD-3, M. Hayford): its CODE V and Zemax readers, its opticalglass catalogues
(Schott, Ohara, Hoya, CDGM, Sumita...) for the media, its global surface transforms for decentres, tilts and
coordinate breaks, and its paraxial first-order data. This module turns its model, once, into the frame of
docs/optics.md: millimetres, the first surface's vertex at the origin, light from the object toward +z.

What rayoptics does not keep (CODE V ``CIR ... OBS`` / ``CIR ... HOL``, Zemax ``OBSC`` / annular ``CLAP``)
is read from the file's text (straylight.optics.file_text).
"""
from __future__ import annotations

import contextlib
import logging
import math
import re
import tempfile
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import atomicio
from straylight.optics.file_text import (
    aperture_shapes, coatings, codev_profile_types, codev_unknown_catalogs, codev_without_titles, extended_aspheres,
    multiconfig, obstructions, radii_without_rdm, zemax_bad_number, zemax_comments, zemax_config_object_distance,
    zemax_coordinate_break_media, zemax_glass_numbers, zemax_index_mirrors, zemax_stop, zemax_truncation, zmx_for_rayoptics,
)
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
    image_semi_diameter_mm: float | None = None  # the image surface's semi-diameter as the file gives it
    model: object = None            # the rayoptics OpticalModel (wavelength set to wavelength_nm)
    scale: float = 1.0              # mm per file unit
    image_heights_mm: list | None = None  # the file's fields as image heights (real or paraxial), when so given


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


def _unread_type(ifc, where: str) -> str | None:
    """Why a surface's Zemax type has no exact part, or None: rayoptics keeps the base sphere/conic of a type it
    does not know (QED_TYPE, SZERNSAG...) and drops the rest of its shape without a word."""
    z_type = getattr(ifc, "z_type", None)
    if z_type is None or z_type in ZEMAX_TYPES_READ:
        return None
    return f"{where}: surface type {z_type} is not supported (sphere, conic, even or odd asphere)"


def _profile(ifc, where: str, problems: list):
    """(type, radius in file units or None, conic, [A4, A6...] in file units, [(p, a_p)] further terms in file
    units: odd powers and r^2) of a surface profile."""
    prof = getattr(ifc, "profile", None)
    kind = type(prof).__name__ if prof is not None else type(ifc).__name__
    cv = float(getattr(prof, "cv", 0.0) or 0.0)
    radius = None if cv == 0.0 else 1.0 / cv
    base: tuple = ("plane" if radius is None else "sphere"), radius, float(getattr(prof, "cc", 0.0) or 0.0), [], []
    unread = _unread_type(ifc, where)
    if unread:
        problems.append(unread)
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
        if not isinstance(used, (tuple, list)):  # the map also counts the names it found nothing for: no substitute
            continue
        glass, cat = (tuple(used) + ("", ""))[:2]
        notes.append(f"glass {name} is not in the catalogues as written; rayoptics substituted {glass}"
                     + (f" ({cat})" if cat else ""))
    return notes


def _glass_name(medium) -> str | None:
    name = medium.name() if hasattr(medium, "name") else str(medium)
    if name.lower() in ("air", ""):
        return None
    return name


def _float_by_stop_size(opm, path: Path, why: str = "aperture floats by stop size (FLOA)", how: str = "") -> str:
    """Zemax ``FLOA`` (aperture "float by stop size"): the entrance pupil is whatever the stop's semi-diameter
    lets through. rayoptics ignores the command and keeps its default 1-unit pupil: the pupil diameter is
    scaled so that the paraxial marginal ray fills the stop (its height is linear in the pupil's). Returns the
    note to warn with."""
    sm = opm["seq_model"]
    stop = sm.stop_surface
    ifc = sm.ifcs[stop] if stop is not None and 0 < stop < len(sm.ifcs) - 1 else None
    if ifc is None or not getattr(ifc, "clear_apertures", None):
        return _limit_by_clear_apertures(opm, path, why + (" and no stop is marked" if ifc is None else
                                                           " and the stop has no semi-diameter"))
    sd = float(ifc.surface_od())
    pupil = opm["optical_spec"]["pupil"]
    y = abs(float(opm["analysis_results"]["parax_data"].ax_ray[stop][0]))
    epd = 2.0 * float(opm["analysis_results"]["parax_data"].fod.enp_radius)
    if not (sd > 0 and y > 0 and math.isfinite(y) and epd > 0):
        return f"{why}{how} but no paraxial ray reaches the stop: pupil as read"
    pupil.key = ("object", "epd")
    pupil.value = epd * sd / y
    _rayoptics_update(opm, path)
    return f"{why}{how}: entrance pupil {pupil.value:.6g} file units, the stop's semi-diameter {sd:g}"


def _limit_by_clear_apertures(opm, path: Path, why: str) -> str:
    """The paraxial limiting aperture, for a file whose stop cannot size the pupil: the entrance pupil scaled by
    the least, over the surfaces whose semi-diameter the file gives, of semi-diameter / |the read pupil's paraxial
    marginal ray height| (linear in the pupil's). A dummy (the same medium both sides: a mount's throat, a field
    stop) counts in a lens, but not in a system with mirrors: the reflex lenses' files draw their central
    obscuration (the secondary's outline, its baffle) so, and the marginal ray passes outside it. Returns the note
    to warn with."""
    sm = opm["seq_model"]
    pupil = opm["optical_spec"]["pupil"]
    pdata = opm["analysis_results"]["parax_data"]
    epd = 2.0 * float(pdata.fod.enp_radius)
    rndx = [abs(float(r[0])) for r in sm.rndx]
    best, dummy = None, None  # (ratio, surface, semi-diameter) of the limiting surface; of the tightest obscuration
    mirrors = any(getattr(ifc, "interact_mode", "") == "reflect" for ifc in sm.ifcs)
    for i in range(1, len(sm.ifcs) - 1):
        ifc = sm.ifcs[i]
        if not (getattr(ifc, "clear_apertures", None) or getattr(ifc, "edge_apertures", None)):
            continue
        sd, y = float(ifc.surface_od()), abs(float(pdata.ax_ray[i][0]))
        if not (sd > 0 and y > 0 and math.isfinite(sd) and math.isfinite(y)):
            continue
        bends = getattr(ifc, "interact_mode", "") == "reflect" or abs(rndx[i] - rndx[i - 1]) > 1e-12
        if not bends and mirrors:
            if dummy is None or sd / y < dummy[0]:
                dummy = (sd / y, i, sd)
        elif best is None or sd / y < best[0]:
            best = (sd / y, i, sd)
    if best is None or not (epd > 0 and math.isfinite(epd)):
        return f"{why}, and no lens or mirror semi-diameter limits the paraxial marginal ray: pupil as read"
    ratio, i, sd = best
    pupil.key = ("object", "epd")
    pupil.value = epd * ratio
    _rayoptics_update(opm, path)
    fno = float(opm["analysis_results"]["parax_data"].fod.fno)
    skipped = ""
    if dummy is not None and dummy[0] < ratio:
        skipped = (f"; not counted: s{dummy[1]}, a dummy among mirrors (semi-diameter {dummy[2]:g}: a central "
                   f"obscuration's outline, which the marginal ray passes outside), {epd * dummy[0]:.4g} by it")
    return (f"{why}: the clear apertures limit the pupil to {pupil.value:.6g} file units (surface s{i}, "
            f"semi-diameter {sd:g}; paraxial f/{fno:.3g}){skipped}")


def require_optical_surface(file: str, surfaces: list) -> None:
    """Refuse, in one line naming the file, a lens with no optical surface (air on both sides of every one: a
    test file of tilted dummies): ``optics info`` and ``optics import`` alike."""
    if not any(not s.dummy for s in surfaces):
        raise OpticsFileError(f"{file}: no optical surface (every surface has air on both sides)")


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
        return (f"the image lies inside a medium of index {last.n:.5g} (after surface {last.index}): an immersed "
                "image (a microscope objective's, in water or oil) is not supported, or the file ends inside the "
                "lens (incomplete?)")
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


@contextlib.contextmanager
def _elements_optional():
    """rayoptics groups a model's surfaces into lens elements (its part tree) at every update, after the
    sequential and paraxial data this import reads; its grammar refuses some fold-mirror layouts with
    coordinate breaks (optiland's simple_fold_mirror_up.zmx: "ParseError: Rule 'image' didn't match"), which
    failed the whole read. Meanwhile a grouping that fails leaves the element model empty: nothing here
    uses it."""
    from parsimonious.exceptions import ParseError
    from rayoptics.elem import parttree

    grouping = parttree.sequence_to_elements

    def tolerant(*args, **kwargs):
        try:
            return grouping(*args, **kwargs)
        except ParseError:
            return None

    parttree.sequence_to_elements = tolerant
    try:
        yield
    finally:
        parttree.sequence_to_elements = grouping


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
    if fmt == "zmx" and any(line.split()[:2] == ["MODE", "NSC"] for line in text.splitlines()[:200]):
        raise OpticsFileError(f"{path}: a non-sequential Zemax file (MODE NSC); optics import reads sequential lens "
                              "files (MODE SEQ): export the lens's sequential prescription")
    cut = zemax_truncation(text) if fmt == "zmx" else None
    if cut:
        raise OpticsFileError(f"{path}: {cut}")
    try:
        with _elements_optional():
            return _read_prescription(path, raw, fmt, text, [], wavelength_nm, glass, force)
    except _ReaderFailure:
        # rayoptics finds the object-side angles of real-image-height fields (Zemax FTYP 3) by a wide-angle
        # search of the real entrance pupil, which fails on some wide-angle lenses: read them again as
        # paraxial image heights (FTYP 2), which only sizes the detector and the field angles
        if fmt != "zmx" or not re.search(r"^\s*FTYP\s+3\b", text, re.M):
            raise
        paraxial = re.sub(r"^(\s*FTYP\s+)3\b", r"\g<1>2", text, count=1, flags=re.M)
        try:
            with _elements_optional():
                return _read_prescription(path, raw, fmt, paraxial, [
                "rayoptics could not aim real rays at the file's real-image-height fields (FTYP 3): fields read as "
                    "paraxial image heights"], wavelength_nm, glass, force)
        except _ReaderFailure:
            pass
        raise


def _real_height_angle_deg(fov, fld, height_mm: float, efl_mm: float) -> float:
    """The object-side field angle (deg) of a real-image-height field ``fld`` (rayoptics aims its chief ray at
    the height); the paraxial angle atan(height / efl) where rayoptics cannot aim it."""
    try:
        with np.errstate(all="ignore"):
            _, d = fov.obj_coords(fld)
        d = np.asarray(d, float)
        angle = math.degrees(math.atan2(math.hypot(d[0], d[1]), d[2]))
        if math.isfinite(angle) and (height_mm == 0.0 or angle > 0.0):
            return angle
    except Exception:  # noqa: BLE001 - rayoptics' aiming failed: the paraxial angle
        pass
    return math.degrees(math.atan2(height_mm, abs(efl_mm)))


def _reserved(label: str) -> bool:
    """A label that cannot name a surface's part: the object and image, the parts the scene builder makes
    (``stop``, ``image``, ``pupil``, ``edge_...``, ``spacer_...``) and another surface's default name (``s7``)."""
    low = label.lower()
    return low in ("obj", "img", "object", "image", "stop", "pupil", "barrel", "barrel_front") \
        or low.startswith(("edge_", "spacer_", "ring_")) \
        or re.fullmatch(r"s\d+", low) is not None


def _read_prescription(path: Path, raw: bytes, fmt: str, text: str, notes: list, wavelength_nm, glass,
                       force: bool) -> Prescription:
    """:func:`read_prescription` of the file's decoded ``text`` (``raw`` its bytes, for CODE V)."""
    as_written = text  # the file's own lines, for a refusal naming one
    if fmt == "seq" and radii_without_rdm(text):
        raw = b"RDM\n" + raw
        text = "RDM\n" + text
        notes.append("no RDM/CUM in the file and its S values as curvatures would give radii smaller than the "
                     "entrance pupil: read as radii (RDM)")
    if fmt == "seq":
        from opticalglass import glassfactory

        untitled, dropped = codev_without_titles(text)
        if dropped:
            raw, text = untitled.encode("utf-8"), untitled

        recatalogued, renamed = codev_unknown_catalogs(text, set(glassfactory._cat_names_uc))
        if renamed:
            raw, text = recatalogued.encode("utf-8"), recatalogued
            for name, full in renamed.items():
                catalogue = full.rpartition("_")[2]
                notes.append(f"glass {full}: catalogue {catalogue} is not one the reader knows; looked up as {name}"
                             f" (--glass {full}=N gives its index)")
                if glass and full in glass and name not in glass:
                    glass = {**glass, name: glass[full]}
        typed, fixed = codev_profile_types(text)
        if fixed:
            raw, text = typed.encode("utf-8"), typed
            notes.append(f"surface(s) {', '.join(map(str, fixed))}: conic or asphere terms without a profile type: read "
                         "as an even asphere (ASP; CON for K alone)")
    if fmt == "zmx":
        text, breaks = zemax_coordinate_break_media(text)
        if breaks:
            notes.append(f"coordinate break(s) {', '.join(map(str, breaks))} inside a medium: the medium goes on across "
                         "them (as Zemax traces it)")
        bad: list = []
        text, mirrors = zemax_index_mirrors(text, bad)
        if bad:
            raise OpticsFileError(f"{path}: {bad[0]}")
        if mirrors:
            notes.append(f"surface(s) {', '.join(map(str, mirrors))}: a medium of index -1 with no thickness, the sign "
                         "convention of a reflection, read as a mirror (Zemax MIRROR) in the medium it sits in")
    try:
        opm, info = _open_rayoptics(path, fmt, zmx_for_rayoptics(text) if fmt == "zmx" else raw)
    except _ReaderFailure:
        where = zemax_bad_number(as_written) if fmt == "zmx" else None
        if where is None:
            raise
        raise _ReaderFailure(f"{path}: the Zemax reader could not parse it ({where})") from None
    glass = dict(glass or {})
    sm = opm["seq_model"]
    stop = zemax_stop(fmt, text)
    if stop is not None and 0 < stop < len(sm.ifcs) - 1 and sm.stop_surface != stop:
        sm.stop_surface = stop  # rayoptics drops a STOP on surface 1 (zemax_stop): the pupil follows the file's stop
        opm.update_model()
    # a surface type with no exact part is the file's blocker: said before any glass the file may also lack (a
    # glass refusal first sent YuryStrelkov's F07g04 user to --glass, and then to its 9 FZERNSAG surfaces)
    types = [why for i, ifc in enumerate(sm.ifcs[1:-1], start=1) if (why := _unread_type(ifc, f"surface {i}"))]
    if types and not force:
        raise OpticsFileError(f"{path}: {types[0]}" + (f" (and {len(types) - 1} more)" if len(types) > 1 else ""))
    # glasses the catalogues lack: --glass NAME=N, or refused naming them
    from opticalglass.opticalmedium import ConstantIndex

    missing = []
    file_numbers = zemax_glass_numbers(fmt, text)
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
                missing.append((gname, gi))
            else:
                gap.medium = ConstantIndex(float(glass[match]), gname)
    if missing:
        unknown = sorted({g for g, _ in missing})
        where = ", ".join(str(i) for _, i in missing[:6]) + (" ..." if len(missing) > 6 else "")
        raise OpticsFileError(f"{path}: unknown glass {', '.join(unknown)} after surface(s) {where} (not in the "
                              f"Schott, Ohara, Hoya, CDGM, Sumita catalogues nor docs/optics.md's other materials, and "
                              f"the file gives no index there); give its index with --glass {unknown[0]}=N")
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
    for i, ext in extended_aspheres(fmt, text).items():
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
        notes.append(_float_by_stop_size(opm, path, "the file gives no aperture (ENPD, FNUM, OBNA or FLOA)",
                                         ": the stop's size sets it, as FLOA"))
    else:
        _rayoptics_update(opm, path)
    obj_dist = float(sm.gaps[0].thi) * scale
    if abs(obj_dist) < 1e8 and not math.isinf(obj_dist):
        raise OpticsFileError(f"{path}: object at a finite distance ({obj_dist:g} mm); optics import models an "
                              "object at infinity (a collimated source)")
    nconf = multiconfig(fmt, text)
    near = zemax_config_object_distance(fmt, text) if nconf > 1 else None
    if near is not None:  # the surface data's infinite object is not configuration 1's (a macro lens): refused alike
        raise OpticsFileError(f"{path}: object at a finite distance ({near * scale:g} mm, configuration 1's THIC 0 "
                              "operand; the surface data's object at infinity is no configuration of the file); "
                              "optics import models an object at infinity (a collimated source)")
    if nconf > 1:
        notes.append(f"multi-configuration file ({nconf} configurations): configuration 1 imported")
    obstr = obstructions(fmt, text)
    coats = coatings(fmt, text)
    apertures = aperture_shapes(fmt, text)

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
    comments = zemax_comments(fmt, text)
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
        label = (getattr(ifc, "label", "") or "").strip() or comments.get(i, "")
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
        if len(group) == 1 and re.fullmatch(r"[A-Za-z0-9_.\-]+", label) and not _reserved(label):
            group[0].name = label
    if problems and not force:
        raise OpticsFileError(f"{path}: {problems[0]}" + (f" (and {len(problems) - 1} more)" if len(problems) > 1
                                                          else "") + "; --force imports it approximated")
    notes += [p + ": imported as its base sphere/conic (--force)" for p in problems]

    require_optical_surface(str(path), surfaces)
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
    elif tuple(fov.key) == ("image", "real height") and not afocal:
        # real image heights (Zemax FTYP 3): the object-side angle of the chief ray rayoptics aims at each height
        # (the Wray 64 mm f/0.7's 13.5 mm is 8.69 deg, not atan(13.5 / efl) = 11.89 deg, where no ray passes)
        fields_deg = [_real_height_angle_deg(fov, f, y * scale, efl) for f, y in zip(fov.fields, fields)]
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
        image_semi_diameter_mm=given_sd[n_ifc - 1] * scale if n_ifc - 1 in given_sd else None,
        model=opm, scale=scale,
        image_heights_mm=[abs(y) * scale for y in fields] if fov.key[0] == "image" and not afocal else None)
