"""Measured BRDF scans: the CSV of CONTRACTS §2, read, validated, written.

A scan file is UTF-8 text: ``# key: value`` metadata lines, one header row, then
one data row per measured point, with the columns of :data:`CSV_COLUMNS` (that
order when written; any order, extra columns ignored, when read).

Angles are degrees in the file and in the ``*_deg`` arrays of :class:`Scan`; the
radian properties ``theta_i``, ``theta_r``, ``phi_r`` convert once, here. A
negative ``theta_r_deg`` is read as the mirror direction: ``(|theta_r|, phi_r + 180)``
(a signed in-plane arm angle), so the radian properties always have
``theta_r >= 0``.

A NaN, infinite, zero or negative ``brdf_per_sr`` is kept (lock-ins read below zero at the
noise floor; an overloaded one may write inf) and marked in :attr:`Scan.flagged`; fits skip those points.
A NaN ``brdf_std_per_sr`` means "unknown" (e.g. a single reading); an infinite one, or a file with no data
rows, is refused naming the file (and the line and column).
"""
from __future__ import annotations

import csv
import dataclasses
import io
import math
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

import atomicio
from atomicio.inputs import InputFileError, read_input_text

CSV_COLUMNS = (
    "wavelength_nm",
    "polarization",
    "theta_i_deg",
    "theta_r_deg",
    "phi_r_deg",
    "brdf_per_sr",
    "brdf_std_per_sr",
    "n_repeats",
)

#: Metadata keys a rig writes (CONTRACTS §2); readers accept files lacking any of them.
METADATA_KEYS = (
    "sample",
    "rig.arm_mm",
    "rig.slit_width_mm",
    "rig.slit_height_mm",
    "rig.beam_diameter_mm",
    "rig.sample_width_mm",
    "date",
)

SCAN_POLARIZATIONS = ("s", "p", "u")


class ScanError(ValueError):
    """Malformed scan: the message names the file, line and column.

    Attributes ``path``, ``line`` (1-based, or None) and ``column`` (name, or None)
    repeat what the message says, for programs.
    """

    def __init__(self, message: str, path=None, line=None, column=None):
        where = []
        if path is not None:
            where.append(str(path))
        if line is not None:
            where.append(f"line {line}")
        if column is not None:
            where.append(f"column {column!s}")
        super().__init__(f"{', '.join(where)}: {message}" if where else message)
        self.path = path
        self.line = line
        self.column = column


def _float_array(values, name):
    arr = np.atleast_1d(np.asarray(values, dtype=float))
    if arr.ndim != 1:
        raise ScanError(f"{name} must be one-dimensional, got shape {arr.shape}")
    return arr


@dataclass(frozen=True, eq=False)
class Scan:
    """One measured scan (any number of incidence angles and polarizations).

    Attributes
    ----------
    wavelength_nm, theta_i_deg, theta_r_deg, phi_r_deg : (n,) float64
    polarization : (n,) str, each ``"s"``, ``"p"`` or ``"u"``
    brdf_per_sr, brdf_std_per_sr : (n,) float64, 1/sr (std is absolute; NaN = unknown)
    n_repeats : (n,) int64
    metadata : dict[str, str] from the ``# key: value`` lines
    path : pathlib.Path or None, the file it was read from
    """

    wavelength_nm: np.ndarray
    polarization: np.ndarray
    theta_i_deg: np.ndarray
    theta_r_deg: np.ndarray
    phi_r_deg: np.ndarray
    brdf_per_sr: np.ndarray
    brdf_std_per_sr: np.ndarray
    n_repeats: np.ndarray
    metadata: dict = field(default_factory=dict)
    path: Path | None = None

    def __post_init__(self):
        cols = {}
        for name in ("wavelength_nm", "theta_i_deg", "theta_r_deg", "phi_r_deg", "brdf_per_sr", "brdf_std_per_sr"):
            cols[name] = _float_array(getattr(self, name), name)
        pol = np.atleast_1d(np.asarray(self.polarization, dtype=str))
        nrep = np.atleast_1d(np.asarray(self.n_repeats))
        n = max(len(v) for v in list(cols.values()) + [pol, nrep])
        for name, arr in list(cols.items()) + [("polarization", pol), ("n_repeats", nrep)]:
            if len(arr) == 1 and n > 1:
                arr = np.repeat(arr, n)
            if len(arr) != n:
                raise ScanError(f"column {name} has {len(arr)} values, expected {n}")
            if name == "n_repeats":
                if arr.size and not np.all(np.asarray(arr, float) == np.round(np.asarray(arr, float))):
                    raise ScanError("n_repeats must be whole numbers")
                arr = np.asarray(arr, dtype=np.int64)
            arr = arr.copy()
            arr.flags.writeable = False
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "metadata", {str(k): str(v) for k, v in dict(self.metadata).items()})
        if self.path is not None:
            object.__setattr__(self, "path", Path(self.path))
        bad = ~np.isin(self.polarization, SCAN_POLARIZATIONS)
        if bad.any():
            raise ScanError(f"unknown polarization {self.polarization[bad][0]!r} (expected s, p or u)")
        for name in ("theta_i_deg", "theta_r_deg"):
            arr = getattr(self, name)
            if not np.all(np.abs(arr) <= 90.0):
                raise ScanError(f"{name} outside [-90, 90]")
        if np.any(self.brdf_std_per_sr < 0):
            raise ScanError("negative brdf_std_per_sr")

    # --- size and selection -------------------------------------------------
    def __len__(self) -> int:
        return len(self.brdf_per_sr)

    def select(self, mask) -> "Scan":
        """A new Scan holding the rows where ``mask`` (bool array or indices) is true."""
        idx = np.asarray(mask)
        return dataclasses.replace(
            self,
            **{name: getattr(self, name)[idx] for name in CSV_COLUMNS},
        )

    def by_polarization(self, polarization: str) -> "Scan":
        return self.select(self.polarization == polarization)

    def by_incidence(self, theta_i_deg: float, atol_deg: float = 1e-6) -> "Scan":
        return self.select(np.abs(self.theta_i_deg - theta_i_deg) <= atol_deg)

    @property
    def incidence_angles_deg(self) -> np.ndarray:
        """Sorted distinct incidence angles, degrees."""
        return np.unique(self.theta_i_deg)

    @property
    def polarizations(self) -> tuple[str, ...]:
        """Distinct polarizations in s, p, u order."""
        present = set(self.polarization.tolist())
        return tuple(p for p in SCAN_POLARIZATIONS if p in present)

    def groups(self):
        """Yield ``((theta_i_deg, polarization), Scan)`` per incidence angle and polarization."""
        for t in self.incidence_angles_deg:
            for p in self.polarizations:
                mask = (self.theta_i_deg == t) & (self.polarization == p)
                if mask.any():
                    yield (float(t), p), self.select(mask)

    # --- derived quantities -------------------------------------------------
    @cached_property
    def flagged(self) -> np.ndarray:
        """(n,) bool: brdf_per_sr is NaN, infinite, zero or negative (kept, but not fittable in log space)."""
        with np.errstate(invalid="ignore"):
            return ~((self.brdf_per_sr > 0) & np.isfinite(self.brdf_per_sr))

    @property
    def theta_i(self) -> np.ndarray:
        """Incidence angle, radians."""
        return np.radians(self.theta_i_deg)

    @property
    def theta_r(self) -> np.ndarray:
        """Viewing angle from the normal, radians, >= 0 (negative file values folded, see module doc)."""
        return np.radians(np.abs(self.theta_r_deg))

    @property
    def phi_r(self) -> np.ndarray:
        """Viewing azimuth, radians in [0, 2 pi); 0 = specular half-plane."""
        phi = np.radians(self.phi_r_deg) + np.where(self.theta_r_deg < 0, np.pi, 0.0)
        return np.mod(phi, 2 * np.pi)

    @property
    def signed_theta_r_deg(self) -> np.ndarray:
        """In-plane viewing angle, degrees: + on the specular side, - on the backscatter side."""
        return np.degrees(self.theta_r) * np.where(np.cos(self.phi_r) >= 0, 1.0, -1.0)

    def metadata_float(self, key: str, default: float | None = None) -> float | None:
        """A numeric metadata value (e.g. ``rig.arm_mm``), or ``default`` when absent."""
        if key not in self.metadata:
            return default
        try:
            return float(self.metadata[key])
        except ValueError:
            raise ScanError(f"metadata {key!r}: {self.metadata[key]!r} is not a number", self.path) from None


def make_scan(*, wavelength_nm, polarization, theta_i_deg, theta_r_deg, phi_r_deg=0.0,
              brdf_per_sr, brdf_std_per_sr=np.nan, n_repeats=1, metadata=None) -> Scan:
    """Build a :class:`Scan` from columns (scalars broadcast), validated like a file."""
    return Scan(
        wavelength_nm=wavelength_nm, polarization=polarization, theta_i_deg=theta_i_deg,
        theta_r_deg=theta_r_deg, phi_r_deg=phi_r_deg, brdf_per_sr=brdf_per_sr,
        brdf_std_per_sr=brdf_std_per_sr, n_repeats=n_repeats, metadata=metadata or {},
    )


# --- reading ------------------------------------------------------------------
def _parse_float(text, path, line, col, name):
    try:
        value = float(text)
    except ValueError:
        raise ScanError(f"{text.strip()!r} is not a number", path, line, f"{col} ({name})") from None
    return value


def _check_repeat(columns: dict, seen: dict, path, lineno: int) -> None:
    """The row just read (the last of ``columns``) may repeat an earlier row's point (same wavelength,
    polarization and angles) only with the same BRDF: two different values at one point would both be
    fitted as truth. Repeats belong in one row (mean, ``brdf_std_per_sr``, ``n_repeats``)."""
    key = (columns["wavelength_nm"][-1], columns["polarization"][-1], columns["theta_i_deg"][-1],
           columns["theta_r_deg"][-1], float(columns["phi_r_deg"][-1]) % 360.0)
    brdf = columns["brdf_per_sr"][-1]
    if not (math.isfinite(brdf) and brdf >= 0):  # a flagged reading (NaN, negative) is kept, never compared
        return
    if key not in seen:
        seen[key] = (lineno, brdf)
        return
    first, before = seen[key]
    if brdf != before:
        raise ScanError(f"repeats the point of line {first} (wavelength {key[0]:g} nm, {key[1]}, theta_i {key[2]:g}, "
                        f"theta_r {key[3]:g}, phi_r {key[4]:g} deg) with another brdf_per_sr ({brdf:g} vs {before:g}); "
                        f"keep one row per point (mean, brdf_std_per_sr, n_repeats)", path, lineno, "brdf_per_sr")


def read_scan(path, allow_empty: bool = False) -> Scan:
    """Read and validate a scan CSV (CONTRACTS §2).

    Raises
    ------
    ScanError
        naming file, line and column for: a missing required column, a non-numeric
        value, a negative ``brdf_std_per_sr``, ``theta_*`` outside [-90, 90], an
        unknown polarization, a non-integer ``n_repeats``, a short row or one with more values than
        the header has columns, an infinite
        ``brdf_std_per_sr``; and a file with no data rows unless ``allow_empty`` (a scan being
        resumed may have stopped after its header).
    """
    path = Path(path)
    try:
        text = read_input_text(path, "scan file", max_bytes=512 * 2**20, encoding="utf-8-sig")
    except FileNotFoundError:
        raise ScanError("no such file", path) from None
    except InputFileError as exc:
        raise ScanError(str(exc).split(": ", 1)[1], path) from None
    except UnicodeDecodeError as exc:
        raise ScanError(f"not UTF-8 text ({exc.reason})", path) from None
    metadata: dict[str, str] = {}
    header = None
    columns = {name: [] for name in CSV_COLUMNS}
    seen: dict = {}  # (wavelength, pol, theta_i, theta_r, phi_r) -> (line, brdf) of its first row
    for lineno, raw in enumerate(text.splitlines(), start=1):
        stripped = raw.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            if header is None:
                body = stripped[1:].strip()
                if ":" in body:
                    key, value = body.split(":", 1)
                    metadata[key.strip()] = value.strip()
            continue  # comments after the header are allowed and ignored
        cells = next(csv.reader([raw]))
        if header is None:
            header = [c.strip() for c in cells]
            missing = [c for c in CSV_COLUMNS if c not in header]
            if missing:
                raise ScanError(f"missing required column {missing[0]!r} (header has: {', '.join(header)})",
                                path, lineno, missing[0])
            index = {name: header.index(name) for name in CSV_COLUMNS}
            continue
        if len(cells) < len(header):
            raise ScanError(f"row has {len(cells)} values, header has {len(header)}", path, lineno,
                            f"{len(cells) + 1} ({header[len(cells)]})")
        if len(cells) > len(header) and any(c.strip() for c in cells[len(header):]):
            raise ScanError(f"row has {len(cells)} values, header has {len(header)}", path, lineno,
                            f"{len(header) + 1} (no column)")
        for name in CSV_COLUMNS:
            col = index[name] + 1
            cell = cells[index[name]].strip()
            if name == "polarization":
                pol = cell.lower()
                if pol not in SCAN_POLARIZATIONS:
                    raise ScanError(f"unknown polarization {cell!r} (expected s, p or u)", path, lineno,
                                    f"{col} ({name})")
                columns[name].append(pol)
                continue
            value = _parse_float(cell, path, lineno, col, name)
            where = (path, lineno, f"{col} ({name})")
            if name in ("theta_i_deg", "theta_r_deg") and not (-90.0 <= value <= 90.0):
                raise ScanError(f"{name} = {cell} is outside [-90, 90]", *where)
            if name == "brdf_std_per_sr" and value < 0:
                raise ScanError(f"negative brdf_std_per_sr {cell}", *where)
            if name == "brdf_std_per_sr" and math.isinf(value):  # NaN is "unknown"; an infinite spread is no reading
                raise ScanError(f"brdf_std_per_sr = {cell} is not finite (nan for an unknown spread)", *where)
            if name in ("wavelength_nm", "phi_r_deg") and not math.isfinite(value):
                raise ScanError(f"{name} = {cell} is not finite", *where)
            if name == "wavelength_nm" and value <= 0:
                raise ScanError(f"wavelength_nm = {cell} must be positive", *where)
            if name == "n_repeats" and not (math.isfinite(value) and value == int(value) and value >= 0):
                raise ScanError(f"n_repeats = {cell} is not a non-negative whole number", *where)
            columns[name].append(value)
        _check_repeat(columns, seen, path, lineno)
    if header is None:
        raise ScanError("no header row (expected columns: " + ", ".join(CSV_COLUMNS) + ")", path, 1)
    if not columns[CSV_COLUMNS[0]] and not allow_empty:
        raise ScanError("no data rows after the header", path)
    return Scan(**columns, metadata=metadata, path=path)


# --- writing ------------------------------------------------------------------
def _fmt(value) -> str:
    if isinstance(value, str):
        return value
    value = float(value)
    if math.isnan(value):
        return "nan"
    return repr(value)  # shortest text that round-trips exactly


def header_text(metadata: dict | None = None) -> str:
    """The metadata lines and the header row, newline-terminated."""
    out = io.StringIO()
    for key, value in (metadata or {}).items():
        key, value = str(key), str(value)
        if "\n" in key or "\n" in value or ":" in key:
            raise ScanError(f"metadata key/value {key!r}: {value!r} must be one line and the key without ':'")
        out.write(f"# {key}: {value}\n")
    out.write(",".join(CSV_COLUMNS) + "\n")
    return out.getvalue()


def format_rows(*, wavelength_nm, polarization, theta_i_deg, theta_r_deg, phi_r_deg,
                brdf_per_sr, brdf_std_per_sr, n_repeats) -> str:
    """Data rows (newline-terminated text) for the given columns; scalars broadcast.

    The values are validated as a :class:`Scan` would be, so a writer cannot
    produce a file that :func:`read_scan` rejects.
    """
    scan = make_scan(wavelength_nm=wavelength_nm, polarization=polarization, theta_i_deg=theta_i_deg,
                     theta_r_deg=theta_r_deg, phi_r_deg=phi_r_deg, brdf_per_sr=brdf_per_sr,
                     brdf_std_per_sr=brdf_std_per_sr, n_repeats=n_repeats)
    return _rows_text(scan)


def _rows_text(scan: Scan) -> str:
    cols = [getattr(scan, name) for name in CSV_COLUMNS]
    lines = []
    for i in range(len(scan)):
        cells = [_fmt(c[i]) if c.dtype.kind != "i" else str(int(c[i])) for c in cols]
        lines.append(",".join(cells) + "\n")
    return "".join(lines)


def append_rows(path, metadata: dict | None = None, **columns) -> None:
    """Append rows to a scan file, creating it (metadata + header) if it does not exist.

    Each call writes whole lines in one ``write``, then flushes and fsyncs, so a
    crash leaves every previously appended row readable. ``columns`` are those of
    :func:`format_rows`.
    """
    path = Path(path)
    text = format_rows(**columns)
    if not path.exists() or path.stat().st_size == 0:
        text = header_text(metadata) + text
    atomicio.append_text(path, text)


def write_scan(path, scan: Scan) -> Path:
    """Write ``scan`` (metadata, header, rows) atomically (:func:`atomicio.write_text`)."""
    path = Path(path)
    text = header_text(scan.metadata) + _rows_text(scan)
    return atomicio.write_text(path, text)
