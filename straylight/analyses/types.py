"""The types the analyses share: what an analysis traces and what a sweep returns.

- :class:`Beam`, :class:`Entrance`, :class:`Setup`: an instrument set up for a PST analysis (the
  built-in tube, a scene file, a model's design, the Cassegrain all become a ``Setup``);
- :class:`PstResult`: a PST sweep (``straylight pst``, the study's PST step), with its flags;
- :class:`SweepResult`: PST over (design value, off-axis angle) (``study``'s design sweeps).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

import atomicio
from straylight.analyses.tables import ResultFiles, TableRepr
from straylight.sources import MIN_RADIUS_MM, CollimatedDisk

if TYPE_CHECKING:
    from geometry.mesh import Scene

DEFAULT_VOV_LIMIT = 0.1  # straylight.analyses.precision.DEFAULT_MAX_VOV: MCNP's reliability check
CSV_COLUMNS = ("off_axis_deg", "azimuth_deg", "pst", "pst_stderr", "entrance_ratio", "entrance_ratio_stderr",
               "detector_w", "detector_stderr_w", "rays", "seconds")
DIAGNOSTIC_COLUMNS = ("vov", "rel_error_of_error", "max_chunk_share", "stop_reason", "rounds")
FLAG_COLUMN = "flags"  # last column of pst.csv, key of each pst.json point (docs/notebook.md, "PST files")
FLAGS = {
    "zero": "no power reached the detector: the PST is below what these rays resolve (0 is not a measurement)",
    "unreliable_error": "the variance of the variance (VOV) is above 0.1 (MCNP's check): rare heavy paths, the "
                        "error bar itself is uncertain (not flagged where the error is under 1e-5 of the point)",
    "target_not_reached": "traced to a target relative error, but a ray or time cap stopped the point first",
}


UNTRUSTED_FLAGS = {"unreliable_error", "target_not_reached"}  # marked on the plot and in the study's table


#: a relative error below this is not flagged unreliable for its VOV (point_flags)
NEGLIGIBLE_REL_ERROR = 1e-5


def point_flags(row: dict) -> str:
    """The ``FLAGS`` that apply to one point (a ``PstResult.rows()`` entry), joined by ';' ('' when none)."""
    out = []
    if not row["pst"] > 0:
        out.append("zero")
    vov = row.get("vov")
    pst, err = row.get("pst"), row.get("pst_stderr")
    # an error bar under NEGLIGIBLE_REL_ERROR of the point (a computed part carries it: direct_area) would stay
    # under 1 % even a thousand times larger: its VOV says nothing a user acts on
    negligible = pst is not None and err is not None and pst > 0 and math.isfinite(err) \
        and err <= NEGLIGIBLE_REL_ERROR * pst
    if vov is not None and math.isfinite(vov) and vov > DEFAULT_VOV_LIMIT and not negligible:
        out.append("unreliable_error")
    if row.get("stop_reason") not in (None, "", "target"):
        out.append("target_not_reached")
    return ";".join(out)



@dataclass(frozen=True, eq=False)
class Beam:
    """A collimated beam: rays start uniformly over a fixed disk.

    center_mm : (3,) disk centre
    axis : (3,) unit vector, disk normal and the beam direction at 0 deg off axis
        (pointing into the instrument)
    radius_mm : disk radius
    power_w : power leaving the disk
    pivot_mm : (3,) or None. None: the disk stays at ``center_mm`` for every tilt
        (BENCHMARK.md). A point: the disk slides in its own plane so that the ray through
        its centre passes through the pivot (keeps a tilted beam on the entrance).
    disk_normal : (3,) or None: normal of the emitting disk when it is not ``axis`` (a scene's
        collimated_disk source may emit obliquely through its disk); None: ``axis``.
    """

    center_mm: np.ndarray  # given as any (3,) array-like; stored as float64 arrays (__post_init__)
    axis: np.ndarray
    radius_mm: float
    power_w: float = 1.0
    pivot_mm: np.ndarray | None = None
    disk_normal: np.ndarray | None = None
    wavelength_nm: float | None = None  # the source's (CONTRACTS §6.5), carried to every tilt

    def __post_init__(self):
        axis = np.asarray(self.axis, dtype=np.float64)
        norm = np.linalg.norm(axis)
        if axis.shape != (3,) or not np.isfinite(norm) or norm == 0:
            raise ValueError(f"beam axis must be 3 finite numbers, not all zero, got {self.axis!r}")
        object.__setattr__(self, "axis", axis / norm)
        object.__setattr__(self, "center_mm", np.asarray(self.center_mm, dtype=np.float64).reshape(3))
        if self.pivot_mm is not None:
            object.__setattr__(self, "pivot_mm", np.asarray(self.pivot_mm, dtype=np.float64).reshape(3))
        if not (np.isfinite(self.radius_mm) and self.radius_mm > 0):
            raise ValueError(f"beam radius_mm must be > 0, got {self.radius_mm!r}")
        n = self.axis if self.disk_normal is None else np.asarray(self.disk_normal, dtype=np.float64).reshape(3)
        if not np.isfinite(np.linalg.norm(n)) or abs(float(np.dot(n, self.axis))) < 1e-9 * np.linalg.norm(n):
            raise ValueError(f"beam disk normal {self.disk_normal!r} must not be perpendicular to the beam")
        object.__setattr__(self, "disk_normal", n / np.linalg.norm(n))

    @property
    def emit_normal(self) -> np.ndarray:
        """The emitting disk's unit normal: ``disk_normal``, which __post_init__ sets (to ``axis`` when not given)."""
        n = self.disk_normal
        assert n is not None
        return n

    @property
    def basis(self) -> tuple[np.ndarray, np.ndarray]:
        """(e1, e2): unit vectors perpendicular to ``axis``; azimuth 0 tilts toward e1.

        e1 is the world axis least aligned with ``axis``, made orthogonal to it, and
        e2 = e1 x axis, so azimuths turn counter-clockwise seen from the sky (about -axis): a
        beam along -z tilts toward +x at azimuth 0 (BENCHMARK.md's (sin a, 0, -cos a)) and
        toward +y at 90 deg.
        """
        k = int(np.argmin(np.abs(self.axis)))
        e1 = np.eye(3)[k] - self.axis[k] * self.axis
        e1 /= np.linalg.norm(e1)
        return e1, np.cross(e1, self.axis)

    def direction(self, off_axis: float, azimuth: float = 0.0) -> np.ndarray:
        """Unit ray direction tilted by ``off_axis`` (rad) toward azimuth ``azimuth`` (rad)."""
        e1, e2 = self.basis
        tilt = np.cos(azimuth) * e1 + np.sin(azimuth) * e2
        return np.cos(off_axis) * self.axis + np.sin(off_axis) * tilt

    def center_for(self, off_axis: float, azimuth: float = 0.0) -> np.ndarray:
        """Disk centre used at this tilt (see ``pivot_mm``)."""
        if self.pivot_mm is None:
            return self.center_mm
        d = self.direction(off_axis, azimuth)
        n = self.emit_normal
        t = float(np.dot(self.pivot_mm - self.center_mm, n) / np.dot(d, n))
        return self.pivot_mm - t * d

    def source(self, off_axis: float, azimuth: float = 0.0):
        """The engine's ``CollimatedDisk`` for this tilt."""
        return CollimatedDisk(center_mm=self.center_for(off_axis, azimuth), normal=self.emit_normal,
                              direction=self.direction(off_axis, azimuth), radius_mm=float(self.radius_mm),
                              power_w=float(self.power_w), wavelength_nm=self.wavelength_nm)

    def cross_section_mm2(self, off_axis: float, azimuth: float = 0.0) -> float:
        """Beam area normal to the rays: pi R^2 |n . d| (the disk seen along the rays)."""
        d = self.direction(off_axis, azimuth)
        return float(np.pi * self.radius_mm**2 * abs(np.dot(self.emit_normal, d)))

    def irradiance_w_per_mm2(self, off_axis: float, azimuth: float = 0.0) -> float:
        """Irradiance on a plane normal to the rays: P / (pi R^2 |n . d|) (P / (pi R^2 cos a) when the
        disk is normal to ``axis``; the disk is fixed, so a tilted beam spreads its power wider)."""
        return self.power_w / self.cross_section_mm2(off_axis, azimuth)


@dataclass(frozen=True, eq=False)
class Entrance:
    """The instrument's entrance: a disk perpendicular to the beam axis.

    The power crossing it, for a beam that covers it, is ``P (r_e / R)^2`` whatever the
    tilt: the beam's projection along the rays onto the entrance plane is a translated copy
    of the source disk.
    """

    center_mm: np.ndarray
    radius_mm: float
    normal: np.ndarray | None = None

    def __post_init__(self):
        object.__setattr__(self, "center_mm", np.asarray(self.center_mm, dtype=np.float64).reshape(3))
        if not (np.isfinite(self.radius_mm) and self.radius_mm >= MIN_RADIUS_MM):
            raise ValueError(f"entrance radius_mm must be >= {MIN_RADIUS_MM:g} mm (a disk with a usable area), "
                             f"got {self.radius_mm!r}")
        if self.normal is not None:
            n = np.asarray(self.normal, dtype=np.float64).reshape(3)
            if not np.isfinite(np.linalg.norm(n)) or np.linalg.norm(n) == 0:
                raise ValueError(f"entrance normal must be 3 finite numbers, not all zero, got {self.normal!r}")
            object.__setattr__(self, "normal", n / np.linalg.norm(n))

    def power_w(self, beam: Beam, off_axis: float, azimuth: float = 0.0) -> float:
        """Beam power crossing the entrance disk; ValueError if the beam does not cover it.

        P r_e^2 |n_e . d| / (R^2 |n_s . d|): the entrance's area seen along the rays over the
        beam's (n_e: entrance normal, default the beam axis; n_s: the source disk's normal).
        """
        d = beam.direction(off_axis, azimuth)
        n = beam.emit_normal
        # walk back from the entrance centre along the rays to the source plane
        t = float(np.dot(self.center_mm - beam.center_mm, n) / np.dot(d, n))
        foot = self.center_mm - t * d
        offset = float(np.linalg.norm(foot - beam.center_for(off_axis, azimuth)))
        if offset + self.radius_mm > beam.radius_mm * (1 + 1e-12):
            raise ValueError(
                f"beam (radius_mm {beam.radius_mm:g}) does not cover the entrance (radius_mm {self.radius_mm:g}) "
                f"at {np.degrees(off_axis):g} deg off axis: offset {offset:.3g} mm; use a larger beam"
            )
        n_e = beam.axis if self.normal is None else self.normal
        return beam.power_w * self.radius_mm**2 * abs(float(np.dot(n_e, d))) / (
            beam.radius_mm**2 * abs(float(np.dot(n, d))))


@dataclass(frozen=True, eq=False)
class Setup:
    """What a PST analysis needs: scene, materials, beam, entrance (optional), detector name."""

    scene: Scene
    materials: dict | None
    beam: Beam
    entrance: Entrance | None
    detector: str
    description: str = ""
    params: dict | None = None
    detector_area_mm2: float | None = None  # None: straylight.detectors.sensitive_area of the part


_SUPERSCRIPT = str.maketrans("0123456789-", "\u2070\u00b9\u00b2\u00b3\u2074\u2075\u2076\u2077\u2078\u2079\u207b")


def plain_log_label(label: str) -> str:
    """A log axis's mathtext tick label (``$\\mathdefault{4\\times10^{-5}}$``, matplotlib's
    LogFormatterSciNotation) as the same text in plain characters (``4×10⁻⁵``)."""
    if not label.startswith("$\\mathdefault{") or not label.endswith("}$"):
        return label
    body = label[len("$\\mathdefault{"):-2].replace("\\times", "\u00d7")
    if "^{" in body:
        head, exponent = body.split("^{", 1)
        body = head + exponent.rstrip("}").translate(_SUPERSCRIPT)
    return body.replace("-", "\u2212")


def _plain_log_ticks(axis) -> None:
    """Label the log ``axis``'s ticks as matplotlib does, in plain text (:func:`plain_log_label`): the
    same labels without the mathtext parser, which took ~0.1 CPU s of each one-point PST plot (pyparsing,
    once per distinct label)."""
    from matplotlib.ticker import LogFormatterSciNotation

    class PlainLogFormatter(LogFormatterSciNotation):
        def __call__(self, x, pos=None):
            return plain_log_label(super().__call__(x, pos))

    axis.set_major_formatter(PlainLogFormatter())
    axis.set_minor_formatter(PlainLogFormatter(labelOnlyBase=False))


def _tight_layout(fig) -> None:
    """``fig.tight_layout()``'s layout (same subplot parameters, same pixels), done once: ``Figure.tight_layout``
    leaves a placeholder layout engine on the figure, for which ``savefig`` lays the figure out again with a
    throwaway draw before the real one (a tenth of a second for a log axis with many ticks)."""
    from matplotlib.layout_engine import TightLayoutEngine

    TightLayoutEngine().execute(fig)


@dataclass(frozen=True, eq=False)
class PstResult(TableRepr, ResultFiles):
    """A PST sweep; arrays have one entry per (off-axis, azimuth) point, in sweep order.

    off_axis_deg, azimuth_deg : (n,) the tilts
    pst, pst_stderr : (n,) detector irradiance / input irradiance
    entrance_ratio, entrance_ratio_stderr : (n,) detector power / entrance power (NaN without entrance)
    detector_w, detector_stderr_w : (n,) detector power for a beam of ``beam_power_w``
    seconds : (n,) wall time of each trace
    """

    off_axis_deg: np.ndarray
    azimuth_deg: np.ndarray
    pst: np.ndarray
    pst_stderr: np.ndarray
    entrance_ratio: np.ndarray
    entrance_ratio_stderr: np.ndarray
    detector_w: np.ndarray
    detector_stderr_w: np.ndarray
    seconds: np.ndarray
    rays: int
    seed: int
    nee: bool
    detector: str
    detector_area_mm2: float
    beam_power_w: float
    description: str = ""
    traces: list = field(default_factory=list, repr=False)
    detector_area_rule: str = ""
    point_rays: np.ndarray | None = None  # (n,) rays traced per point (differs with a precision target)
    diagnostics: list | None = None  # per point: reliability of the error estimate, stop reason, rounds
    precision: dict | None = None  # the target and caps, when traced to a relative error
    diffraction: dict | None = None  # edge diffraction on/off, method and wavelength, when a part diffracts

    def rows(self) -> list[dict]:
        """One dict per point, keys ``CSV_COLUMNS``."""
        return [
            {"off_axis_deg": float(self.off_axis_deg[i]), "azimuth_deg": float(self.azimuth_deg[i]),
             "pst": float(self.pst[i]), "pst_stderr": float(self.pst_stderr[i]),
             "entrance_ratio": float(self.entrance_ratio[i]),
             "entrance_ratio_stderr": float(self.entrance_ratio_stderr[i]),
             "detector_w": float(self.detector_w[i]), "detector_stderr_w": float(self.detector_stderr_w[i]),
             "rays": int(self.rays if self.point_rays is None else self.point_rays[i]),
             "seconds": float(self.seconds[i]), **(self.diagnostics[i] if self.diagnostics else {})}
            for i in range(len(self.pst))
        ]

    def flagged_rows(self) -> list[dict]:
        """:meth:`rows` with each point's ``flags`` (:func:`point_flags`)."""
        return [{**r, FLAG_COLUMN: point_flags(r)} for r in self.rows()]

    def to_pandas(self):
        """The points as a pandas DataFrame (columns of pst.csv; pandas is an optional dependency)."""
        from straylight.analyses.tables import data_frame

        return data_frame(self.flagged_rows(), CSV_COLUMNS + DIAGNOSTIC_COLUMNS + (FLAG_COLUMN,))

    def to_json_dict(self) -> dict:
        clean = [{k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in r.items()}
                 for r in self.flagged_rows()]
        return {"quantity": "point source transmittance",
                "definitions": {"pst": "detector irradiance / beam irradiance normal to the rays",
                                "entrance_ratio": "detector power / beam power crossing the entrance disk"},
                "description": self.description, "detector": self.detector,
                "detector_area_mm2": self.detector_area_mm2, "detector_area_rule": self.detector_area_rule,
                "rays_per_point": self.rays if self.precision is None else None, "seed": self.seed,
                "precision": self.precision,
                "reliability_note": "rel_error_of_error ~ sqrt(vov) / 2; vov > 0.1 (MCNP's check) or a large "
                                    "max_chunk_share means rare heavy paths: the error bar itself is uncertain",
                "nee": self.nee, "beam_power_w": self.beam_power_w, "diffraction": self.diffraction,
                "units": {"off_axis_deg": "deg", "azimuth_deg": "deg", "pst": "1", "pst_stderr": "1",
                          "detector_w": "W", "detector_stderr_w": "W", "detector_area_mm2": "mm^2"},
                "flags": FLAGS, "points": clean}

    def csv_table(self) -> tuple:
        """pst.csv: the CONTRACTS columns, the diagnostics, the flags (pst.json's other keys, such as a
        point's ``strategies_off``, stay in pst.json)."""
        columns = CSV_COLUMNS + DIAGNOSTIC_COLUMNS + (FLAG_COLUMN,)
        return columns, [{k: r[k] for k in columns if k in r} for r in self.flagged_rows()]

    def plot(self, path=None, quantity: str = "pst", ax=None, label_prefix: str = ""):
        """Log-scale plot of ``quantity`` ("pst" or "entrance_ratio") vs off-axis angle, 1-sigma bars.

        Zero values (no light reached the detector) cannot sit on a log axis: they are drawn
        as open triangles on the bottom edge and named in the legend.
        """
        if quantity not in ("pst", "entrance_ratio"):
            raise ValueError(f"quantity must be 'pst' or 'entrance_ratio', got {quantity!r}")
        y, e = getattr(self, quantity), getattr(self, quantity + "_stderr")
        own = ax is None
        if own and path is None:  # a figure for the caller to show: pyplot's
            import matplotlib.pyplot as plt

            fig, ax = plt.subplots(figsize=(7, 4.5), dpi=120)
        elif own:  # a file only: matplotlib's Figure API, without pyplot's import and figure manager
            from matplotlib.backends.backend_agg import FigureCanvasAgg
            from matplotlib.figure import Figure

            fig = Figure(figsize=(7, 4.5), dpi=120)
            FigureCanvasAgg(fig)  # a real renderer for the layout (else each layout prints the figure to get one)
            ax = fig.subplots()
        doubtful = np.array([bool(set(r[FLAG_COLUMN].split(";")) & UNTRUSTED_FLAGS) for r in self.flagged_rows()])
        for phi in np.unique(self.azimuth_deg):
            sel = self.azimuth_deg == phi
            x, yy, ee = self.off_axis_deg[sel], y[sel], e[sel]
            pos = yy > 0
            label = label_prefix + (f"azimuth {phi:g} deg" if len(np.unique(self.azimuth_deg)) > 1 else "")
            line = ax.errorbar(x[pos], yy[pos], yerr=np.minimum(ee[pos], 0.999 * yy[pos]), fmt="o-", ms=4,
                               capsize=3, label=label or None)
            bad = pos & doubtful[sel]
            if np.any(bad):  # the error bar itself cannot be trusted there: say so on the plot
                ax.plot(x[bad], yy[bad], "s", mfc="none", mec="red", mew=1.5, ms=11,
                        label=(label + ": " if label else "") + "error bar NOT reliable (VOV > 0.1 or cap reached)")
            zero = ~pos & np.isfinite(yy)
            if np.any(zero):
                # y in axes units (0 = bottom edge) for x in data units
                ax.plot(x[zero], np.zeros(zero.sum()), "v", mfc="none", ms=7, color=line[0].get_color(),
                        transform=ax.get_xaxis_transform(), clip_on=False,
                        label=(label + ": " if label else "") + "zero (no detected power)")
        ax.set_yscale("log")
        _plain_log_ticks(ax.yaxis)
        ax.set_xlabel("off-axis angle (deg)")
        ax.set_ylabel("PST = E_detector / E_input" if quantity == "pst"
                      else "detector power / entrance power")
        ax.grid(True, which="both", alpha=0.3)
        ax.set_title(f"{'Point source transmittance' if quantity == 'pst' else 'Entrance-normalised ratio'}"
                     + (f" ({self.rays:.2g} rays/point, 1-sigma bars)" if self.precision is None else
                        f" (to {self.precision['target_rel_error']:.1%} rel. error, 1-sigma bars)"), fontsize=10)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8)
        if own:
            _tight_layout(fig)
            if path is not None:
                atomicio.write_figure(fig, path)
        return ax



PARAMETER_LABELS = {
    "vane_count": "number of vanes",
    "vane_inner_radius_mm": "vane hole radius (mm)",
    "vane_thickness_mm": "vane thickness (mm)",
    "vane_bevel_deg": "vane bevel (deg)",
    "length_mm": "tube length (mm)",
}


@dataclass(frozen=True, eq=False)
class SweepResult(ResultFiles):
    """PST over (design value, off-axis angle); arrays are (n_values, n_angles)."""

    parameter: str
    values: np.ndarray
    off_axis_deg: np.ndarray
    pst: np.ndarray
    pst_stderr: np.ndarray
    entrance_ratio: np.ndarray
    entrance_ratio_stderr: np.ndarray
    seconds: np.ndarray
    rays: int
    seed: int
    material: str

    def rows(self) -> list[dict]:
        return [{self.parameter: float(v), "off_axis_deg": float(a), "pst": float(self.pst[i, j]),
                 "pst_stderr": float(self.pst_stderr[i, j]), "entrance_ratio": float(self.entrance_ratio[i, j]),
                 "entrance_ratio_stderr": float(self.entrance_ratio_stderr[i, j]), "rays": self.rays,
                 "seconds": float(self.seconds[i, j])}
                for i, v in enumerate(self.values) for j, a in enumerate(self.off_axis_deg)]

    def to_json_dict(self) -> dict:
        return {"parameter": self.parameter, "values": [float(v) for v in self.values],
                "off_axis_deg": [float(a) for a in self.off_axis_deg], "rays_per_point": self.rays,
                "seed": self.seed, "material": self.material, "points": self.rows()}

    def csv_table(self) -> tuple:
        """sweep.csv: one row per (value, angle)."""
        rows = self.rows()
        return list(rows[0]), rows

    def best(self, angle_index: int = -1) -> float:
        """Design value with the lowest PST at one angle (ties: the first)."""
        return float(self.values[int(np.nanargmin(self.pst[:, angle_index]))])

    def plot(self, path=None, ax=None):
        """PST vs the design parameter, one line per off-axis angle, log y, 1-sigma bars."""
        import matplotlib.pyplot as plt

        own = ax is None
        if own:
            fig, ax = plt.subplots(figsize=(7, 4.5), dpi=120)
        for j, a in enumerate(self.off_axis_deg):
            y, e = self.pst[:, j], self.pst_stderr[:, j]
            pos = y > 0
            ax.errorbar(self.values[pos], y[pos], yerr=np.minimum(e[pos], 0.999 * y[pos]), fmt="o-", ms=4,
                        capsize=3, label=f"{a:g} deg off axis")
            if np.any(~pos):
                ax.plot(self.values[~pos], np.zeros((~pos).sum()), "v", mfc="none", ms=7,
                        transform=ax.get_xaxis_transform(), clip_on=False, color=ax.lines[-1].get_color(),
                        label=f"{a:g} deg: zero detected")
        ax.set_yscale("log")
        ax.set_xlabel(PARAMETER_LABELS.get(self.parameter, self.parameter))
        ax.set_ylabel("PST = E_detector / E_input")
        if self.parameter == "vane_count":
            ax.set_xticks(self.values)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
        ax.set_title(f"Design sweep: {PARAMETER_LABELS.get(self.parameter, self.parameter)}\n"
                     f"coating {self.material}; {self.rays:.2g} rays per point, 1-sigma error bars", fontsize=10)
        if own:
            _tight_layout(fig)
            if path is not None:
                atomicio.write_figure(fig, path)
        return ax
