"""The notebook API: load an instrument, run an analysis, get a typed result (docs/notebook.md).

    import straylight.api as sl

    inst = sl.load("scope.toml")                 # a scene file (CONTRACTS §6), or sl.load(builtin="tube")
    pst = inst.pst([0, 10, 20, 30], rays=50_000, seed=1)      # PstResult
    pst = inst.pst([10, 20], precision=sl.Precision(0.05), execution=sl.Execution(threads=2))
    pst.to_pandas(); pst.plot()
    paths = inst.paths(20, rays=100_000, seed=1)              # PathReport (.trace: the TraceResult)
    crit = inst.critical(20, rays=50_000, seed=1)             # CriticalReport
    inst.view3d("view.html", 20)                              # the interactive 3-D view
    th = sl.thermal("scope.toml", (8, 12), rays=200_000)      # ThermalResult (parts at temperature_k)

Results are frozen dataclasses with named fields, ``to_pandas()`` (pandas is optional) and
``plot()`` (matplotlib). The ``straylight pst``, ``paths`` and ``critical`` commands are built on
these calls: the same arguments and seed give the same numbers (the docs' example is run by a test
against the commands). Angles are in degrees here, as on the command line.
"""
from __future__ import annotations

import dataclasses

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from straylight.analyses.builtin import DEFAULT_MATERIAL
from straylight.analyses.types import Entrance, PstResult, Setup
from straylight.execution import Execution
from straylight.stop_rule import Precision

if TYPE_CHECKING:
    from straylight.analyses.critical import CriticalReport
    from straylight.analyses.paths_report import PathReport

__all__ = ["BUILTINS", "Execution", "Instrument", "PartInfo", "Precision", "exchange", "load", "precision_target",
           "thermal", "thermal_scene"]

BUILTINS = ("tube", "cassegrain")


@dataclass(frozen=True)
class PartInfo:
    """One part of the loaded instrument: name, role, material name, triangle count."""

    name: str
    role: str
    material: str | None
    triangles: int


def load(scene=None, *, builtin: str | None = None, detector: str | None = None, material: str | None = None,
         entrance_center_mm=None, entrance_radius_mm: float | None = None, **tube_params) -> Instrument:
    """An :class:`Instrument` from a scene file (``scene``) or a built-in (``builtin="tube"`` or ``"cassegrain"``).

    detector : the detector part (default: the scene's [analysis] detector, or its only one)
    material : built-in tube only: the coating of wall, vanes and end plate (default z302_sample_b)
    entrance_center_mm, entrance_radius_mm : scene file only: override its [analysis] entrance (together)
    tube_params : built-in tube only: ``geometry.parts.tube.TubeParams`` fields (``vane_count=5``, ...)
    """
    if (scene is None) == (builtin is None):
        raise ValueError("give either a scene file or builtin='tube' (or 'cassegrain')")
    if builtin is not None and builtin not in BUILTINS:
        raise ValueError(f"builtin must be one of {', '.join(BUILTINS)}, got {builtin!r}")
    if (entrance_radius_mm is None) != (entrance_center_mm is None):
        raise ValueError("give entrance_center_mm and entrance_radius_mm together")
    if builtin == "cassegrain":
        from straylight.analyses.telescope import cassegrain_setup

        given = [k for k, v in {"material": material, "detector": detector, **tube_params}.items() if v is not None]
        if given or entrance_radius_mm is not None:
            raise ValueError(f"{', '.join(given) or 'entrance'} applies to the built-in tube, not to the Cassegrain")
        return Instrument(cassegrain_setup(), "builtin cassegrain")
    if builtin == "tube":
        from straylight.analyses.builtin import tube_setup

        if entrance_radius_mm is not None:
            raise ValueError("the entrance of the built-in tube is fixed (give it in a scene file's [analysis])")
        setup = tube_setup(material=material or DEFAULT_MATERIAL,
                           **{k: v for k, v in tube_params.items() if v is not None})
        if detector is not None:
            setup = Setup(setup.scene, setup.materials, setup.beam, setup.entrance, detector, setup.description,
                          setup.params)
        return Instrument(setup, "builtin tube")
    given = [k for k, v in {"material": material, **tube_params}.items() if v is not None]
    if given:
        raise ValueError(f"{', '.join(given)} applies to the built-in tube, not to a scene file")
    from straylight.analyses.scene_setup import scene_setup

    entrance = None if entrance_radius_mm is None else Entrance(center_mm=entrance_center_mm,
                                                                radius_mm=entrance_radius_mm)
    return Instrument(scene_setup(scene, detector=detector, entrance=entrance), str(scene))


def thermal_scene(scene):
    """The :class:`~straylight.thermal.model.ThermalScene` of a scene file (its ``[[source]]`` entries are
    ignored: CONTRACTS §7; a thermal scene may have none)."""
    import warnings

    from straylight.scene import SceneWarning, load_scene
    from straylight.thermal.model import thermal_scene as build

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)  # non-watertight sheets are normal here
        rs = load_scene(Path(scene), sources=False, check_watertight=False)  # its warnings are dropped anyway
    return build(rs.scene, rs.materials)


def thermal(scene, band_um, *, rays: int | None = None, target_rel_error: float | None = None, seed: int = 0,
            method: str = "reverse", max_seconds: float | None = None, temperature_k=(), sweep=None,
            execution=None):
    """Self-emission in the band ``band_um`` (lo, hi) reaching each detector of a scene file (``straylight
    thermal``, CONTRACTS §7.1): a :class:`~straylight.thermal.run.ThermalResult`. ``scene``: a file or a
    ThermalScene (:func:`thermal_scene`, to load once and run several bands). ``temperature_k``: "PART=K"
    settings over the scene's (PART may be a pattern, ``vane_*``); ``sweep``: further temperature sets
    on the same paths (``ThermalResult.sweep``; straylight.thermal.run.thermal). ``execution``: a
    :class:`~straylight.execution.Execution` (threads in this process; the numbers never depend on it)."""
    from straylight.thermal.model import ThermalScene
    from straylight.thermal.planck import check_band
    from straylight.thermal.run import DEFAULT_MAX_SECONDS
    from straylight.thermal.run import thermal as run

    check_band(*band_um)
    from straylight.thermal.model import temperatures_with

    ts = scene if isinstance(scene, ThermalScene) else thermal_scene(scene)
    if temperature_k:
        ts = dataclasses.replace(ts, temperature_k=temperatures_with(ts, temperature_k))
    return run(ts, tuple(band_um), n_rays=rays, target_rel_error=target_rel_error, seed=int(seed), method=method,
               max_seconds=DEFAULT_MAX_SECONDS if max_seconds is None else float(max_seconds), sweep=sweep,
               execution=execution)


def exchange(scene, band_um, *, rays: int, seed: int = 0):
    """Radiative distribution factors D_ij of a scene file's parts in the band (``straylight exchange``,
    CONTRACTS §7.2): a :class:`~straylight.thermal.exchange.ExchangeResult`."""
    from straylight.thermal.exchange import exchange as run
    from straylight.thermal.model import ThermalScene
    from straylight.thermal.planck import check_band

    check_band(*band_um)
    if int(rays) < 2:
        raise ValueError(f"rays must be >= 2, got {rays!r}")
    ts = scene if isinstance(scene, ThermalScene) else thermal_scene(scene)
    return run(ts, tuple(band_um), n_rays=int(rays), seed=int(seed))


def precision_target(target_rel_error: float | None, max_rays=None, max_seconds=None, max_vov=None):
    """A :class:`~straylight.analyses.precision.Precision` (None without a target); defaults for caps not given."""
    from straylight.analyses.precision import DEFAULT_MAX_RAYS, DEFAULT_MAX_VOV, Precision

    if target_rel_error is None:
        given = [k for k, v in {"max_rays": max_rays, "max_seconds": max_seconds, "max_vov": max_vov}.items()
                 if v is not None]
        if given:
            raise ValueError(f"{', '.join(given)} need target_rel_error")
        return None
    if not 0 < target_rel_error < 1:
        raise ValueError(f"target_rel_error must be in (0, 1), e.g. 0.02, got {target_rel_error}")
    return Precision(target_rel_error, max_rays=int(max_rays) if max_rays is not None else DEFAULT_MAX_RAYS,
                     max_seconds=max_seconds if max_seconds is not None else float("inf"),
                     max_vov=max_vov if max_vov is not None else DEFAULT_MAX_VOV)


def _angle_rad(value_deg: float, name: str) -> float:
    if not -90 < float(value_deg) < 90:
        raise ValueError(f"{name} must be in (-90, 90) deg, got {value_deg}")
    return math.radians(float(value_deg))


@dataclass(frozen=True, eq=False)
class Instrument:
    """A loaded instrument (:class:`~straylight.analyses.types.Setup`: scene, materials, beam, entrance,
    detector) and the analyses that run on it. ``execution`` on each call (:class:`straylight.execution.Execution`:
    threads, workers, scheduler, client, progress) chooses where it runs (default: this process, quiet);
    it never changes the numbers."""

    setup: Setup = field(repr=False)
    source: str = ""

    def __repr__(self) -> str:
        scene = self.setup.scene
        return (f"Instrument({self.source!r}: {len(scene.parts)} parts, {len(scene.triangles_mm)} triangles, "
                f"detector {self.setup.detector or '(the only one)'})")

    @property
    def parts(self) -> list[PartInfo]:
        return [PartInfo(p.name, p.role, p.material, len(p.faces)) for p in self.setup.scene.parts]

    @property
    def detector(self) -> str:
        from straylight.analyses.pst import detector_name

        return detector_name(self.setup.scene, self.setup.detector)

    def pst(self, angles_deg: float | Sequence[float], azimuths_deg: float | Sequence[float] = (0.0,), *,
            rays: int = 100_000, seed: int = 0, precision: Precision | None = None,
            execution: Execution | None = None, nee: bool = True, diffraction: bool = True,
            wavelength_nm: float | None = None, estimators: str = "default",
            checkpoint_dir: str | Path | None = None, resume: bool = False,
            target_rel_error: float | None = None, max_rays: int | None = None, max_seconds: float | None = None,
            max_vov: float | None = None) -> PstResult:
        """Point source transmittance at every (angle, azimuth): a :class:`~straylight.analyses.types.PstResult`.

        ``rays`` per point, or ``precision=Precision(target_rel_error, max_rays=..., max_seconds=...,
        max_vov=...)``: each point traced until its relative standard error is at most the target
        (docs/study.md); the short form ``target_rel_error=`` (with ``max_rays``, ``max_seconds``,
        ``max_vov``) makes the same Precision. ``execution``: where it runs (:class:`Execution`).
        Each point has its own seed derived from ``seed``.
        ``diffraction``: the parts marked ``diffraction = "edges"`` bend light (HURB, docs/diffraction.md)
        or, False, pure geometric optics; ``wavelength_nm`` overrides the beam's (CONTRACTS §6.5).
        ``estimators``: the estimator set (:mod:`straylight.analyses.estimators`: "default", or one registered).
        """
        import numpy as np

        from straylight.analyses.estimators import estimator_options
        from straylight.analyses.pst import pst_sweep
        from straylight.trace import PhysicsOptions, TraceOptions

        if precision is not None:
            loose = [k for k, v in {"target_rel_error": target_rel_error, "max_rays": max_rays,
                                    "max_seconds": max_seconds, "max_vov": max_vov}.items() if v is not None]
            if loose:
                raise ValueError(f"give precision=Precision(...) or {', '.join(loose)}, not both")
            if not isinstance(precision, Precision):
                raise TypeError(f"precision must be a straylight.api.Precision, got {type(precision).__name__}")
        else:
            precision = precision_target(target_rel_error, max_rays, max_seconds, max_vov)
        setup = self.setup
        if wavelength_nm is not None:
            if not float(wavelength_nm) > 0:
                raise ValueError(f"wavelength_nm must be > 0, got {wavelength_nm}")
            setup = replace(setup, beam=replace(setup.beam, wavelength_nm=float(wavelength_nm)))
        physics = PhysicsOptions(diffraction="scene" if diffraction else "off")
        options = estimator_options(estimators, TraceOptions(physics=physics), materials=setup.materials)
        return pst_sweep(setup, np.radians(np.atleast_1d(np.asarray(angles_deg, dtype=float))), np.radians(np.atleast_1d(azimuths_deg)),
                         n_rays=int(rays) if precision is None else 1, seed=int(seed), nee=nee, options=options,
                         execution=execution, precision=precision, checkpoint_dir=checkpoint_dir, resume=resume)

    def paths(self, angle_deg: float, azimuth_deg: float = 0.0, *, rays: int = 100_000, seed: int = 0,
              nee: bool = True, group_by: str = "sequence", ancestry=None,
              execution: Execution | None = None) -> PathReport:
        """Stray-light paths to the detector, ranked: a :class:`~straylight.analyses.paths_report.PathReport`
        whose ``trace`` is the :class:`~straylight.trace.TraceResult` (absorbed power per part, maps...)."""
        from straylight.analyses.paths_report import paths_analysis

        report, res = paths_analysis(self.setup, _angle_rad(angle_deg, "angle_deg"), math.radians(azimuth_deg),
                                     n_rays=int(rays), seed=int(seed), nee=nee, group_by=group_by,
                                     ancestry=ancestry, execution=execution)
        return replace(report, trace=res)

    def critical(self, angle_deg: float, azimuth_deg: float = 0.0, *, rays: int = 100_000, seed: int = 0,
                 execution: Execution | None = None) -> CriticalReport:
        """Critical and illuminated parts: a :class:`~straylight.analyses.critical.CriticalReport`."""
        from straylight.analyses.critical import critical_objects

        if int(rays) < 2:
            raise ValueError(f"rays must be >= 2, got {rays}")
        return critical_objects(self.setup, _angle_rad(angle_deg, "angle_deg"), math.radians(azimuth_deg),
                                n_rays=int(rays), seed=int(seed), execution=execution)

    def view3d(self, path, angle_deg: float = 20.0, azimuth_deg: float = 0.0, *, rays: int = 50_000, seed: int = 0,
               paths=None, max_triangles: int | None = None) -> Path:
        """Write the interactive 3-D view (straylight.view3d) at this angle: parts coloured by absorbed
        power, the ranked paths' sample rays. ``paths``: a PathReport of this angle to reuse (else traced
        with ``rays`` and ``seed``)."""
        from straylight import view3d

        report = paths if paths is not None else self.paths(angle_deg, azimuth_deg, rays=rays, seed=seed)
        if report.trace is None:
            raise ValueError("paths has no trace: use the PathReport that Instrument.paths returned")
        extra: dict[str, Any] = {} if max_triangles is None else {"max_triangles": int(max_triangles)}
        return view3d.write_view3d(path, self.setup, report.trace, report, _angle_rad(angle_deg, "angle_deg"),
                                   math.radians(azimuth_deg), seed=seed, **extra)
