"""The reflectometer's ray-traced twin: its CAD, a laser beam and the Monte Carlo engine.

Where :mod:`rig.forward` integrates the BRDF over the slit and beam by quadrature, the twin
builds the rig itself (:mod:`geometry.parts.reflectometer`: sample plate on the rotation
axis, holder and post, slit plate and detector sheet on the arm), lights it with a
collimated laser beam and traces it with :func:`straylight.trace.trace`. The reading is
the seed paper's (PHYSICS §4)::

    BRDF_measured = P_detector / (P_incident * Omega_slit * cos(theta_r)),
    Omega_slit = slit_width_mm * slit_height_mm / arm_mm**2,

with ``theta_r`` the arm's set-point, and its Monte Carlo standard error is the detector
power's, scaled by the same factor.

Geometry (lab frame of :mod:`geometry.parts.reflectometer`): the laser travels along -z
and hits the origin; the rotation axis is y. The parts are tessellated once (cached per
geometry) at theta_i = theta_r = 0 and moved by rigid rotations about y for each set-point:
the sample group (sample, holder, post) by ``R_y(theta_i + stage_offset) R_x(-tilt)``,
the arm group (slit plate, detector) by ``R_y(theta_i +/- theta_r + arm_offset)``
(+ on the specular side, - on the backscatter side), the alignment errors of
:class:`rig.instrument.RigConfig` entering as in :mod:`rig.forward`.

Estimators. Next-event estimation (NEE) toward the detector sheet is efficient where the
BRDF is smooth over the slit (diffuse wings); a narrow specular lobe (or a mirror) is
better counted by the random walk itself (rays that pass the slit). ``estimator="auto"``
runs a short pilot of both on an independent random stream and traces the set-point with
the one of lower variance per ray; the pilot's numbers are then discarded, so the choice
cannot bias the estimate.

Seeds: each set-point is traced with its own seed derived from (seed, theta_i, theta_r,
phi_r, polarization), so a point's value does not depend on the other points of the scan,
and the engine makes it independent of batch size and worker count.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

import atomicio
from rig.instrument import NOMINAL, RigConfig
from rig.rotations import matrix_about_x, matrix_about_y

ESTIMATORS = ("auto", "nee", "walk")
PROFILES = ("gaussian", "tophat")
POLARIZATIONS = ("s", "p", "u")
SAMPLE_GROUP = ("sample", "holder", "holder_post")
ARM_GROUP = ("slit_plate", "detector")


class TwinError(ValueError):
    """Bad input to the twin; the message names the parameter."""


@dataclass(frozen=True)
class Mirror:
    """A specular sample: reflects the beam with reflectance ``reflectance`` (engine role "mirror").

    Its BRDF is a delta function, so the fast model cannot evaluate it; the rig reads its own
    angular response (PHYSICS §5).
    """

    reflectance: float = 1.0

    def __post_init__(self):
        if not (0.0 <= float(self.reflectance) <= 1.0):
            raise TwinError(f"mirror reflectance must be in [0, 1], got {self.reflectance!r}")


@dataclass(frozen=True)
class TwinConfig:
    """What the twin needs beyond :class:`rig.instrument.RigConfig` (lengths in mm).

    Parameters
    ----------
    beam_profile : "gaussian" (1/e^2 diameter = ``RigConfig.beam_diameter_mm``, as the fast
        model) or "tophat" (uniform disk of that diameter).
    slit_plate_thickness_mm : thickness of the slit plate. A thin foil by default: the fast model
        has no slit depth, and a 1 mm plate vignettes the 0.2 mm slit by up to ~5 % at grazing
        footprints.
    detector_gap_mm : gap between the slit plate's back and the detector sheet.
    detector_margin_mm : the detector sheet is the slit plus this margin on every side (it must
        catch everything that passes the slit; a small sheet keeps NEE efficient).
    sample_height_mm : sample extent out of the plane of incidence (its width is
        ``RigConfig.sample_width_mm``).
    holder_rd : 0 makes holder and post perfect absorbers; > 0 makes them Lambertian
        surfaces of that reflectance (stray light from the mount).
    source_standoff_mm : where the (virtual) beam rays start, upstream of the sample; None (default):
        beyond the arm's orbit (1.25 arm + 10 mm), so that near retroreflection the arm shadows the
        beam as on the real rig.
    tolerance_mm : chord tolerance of the tessellation (only the post is curved).
    estimator : "auto", "nee" or "walk" (module docstring).
    pilot_fraction : pilot rays per estimator, as a fraction of the set-point's rays (auto only).
    """

    beam_profile: str = "gaussian"
    slit_plate_thickness_mm: float = 0.05
    detector_gap_mm: float = 0.2
    detector_margin_mm: float = 0.1
    sample_height_mm: float = 25.4
    holder_rd: float = 0.0
    source_standoff_mm: float | None = None
    tolerance_mm: float = 0.05
    estimator: str = "auto"
    pilot_fraction: float = 0.1

    def __post_init__(self):
        if self.beam_profile not in PROFILES:
            raise TwinError(f"beam_profile must be one of {', '.join(PROFILES)}, got {self.beam_profile!r}")
        if self.estimator not in ESTIMATORS:
            raise TwinError(f"estimator must be one of {', '.join(ESTIMATORS)}, got {self.estimator!r}")
        for name in ("slit_plate_thickness_mm", "detector_gap_mm", "detector_margin_mm", "sample_height_mm",
                     "source_standoff_mm", "tolerance_mm", "pilot_fraction"):
            value = getattr(self, name)
            if value is None and name == "source_standoff_mm":
                continue
            if not (math.isfinite(value) and value > 0):
                raise TwinError(f"{name} must be a finite number > 0, got {value!r}")
        if not (0.0 <= self.holder_rd < 1.0):
            raise TwinError(f"holder_rd must be in [0, 1), got {self.holder_rd!r}")


DEFAULT_TWIN = TwinConfig()


# ------------------------------------------------------------------ source


@dataclass(frozen=True, eq=False)
class LaserBeam:
    """Collimated laser beam with its waist on the sample (a virtual source for the engine).

    Rays cross the plane through ``center_mm`` normal to ``direction`` at transverse positions
    drawn from the profile (Gaussian: intensity sigma = diameter / 4, i.e. 1/e^2 diameter;
    top-hat: uniform disk of the diameter) and start ``standoff_mm`` upstream. With
    ``divergence_mrad`` > 0 each ray is tilted in the plane of incidence (about ``axis_v``)
    by a Gaussian angle of that sigma, as in :mod:`rig.forward`.
    """

    center_mm: np.ndarray
    direction: np.ndarray
    axis_u: np.ndarray
    diameter_mm: float
    profile: str = "gaussian"
    divergence_mrad: float = 0.0
    standoff_mm: float = 40.0
    power_w: float = 1.0

    def emit(self, u):
        """u : (n, 4) uniforms -> (origins (n, 3), unit directions (n, 3)), mm."""
        d0 = np.asarray(self.direction, float)
        eu = np.asarray(self.axis_u, float)
        ev = np.cross(d0, eu)
        phi = 2.0 * np.pi * u[:, 1]
        if self.profile == "gaussian":
            r = 0.25 * self.diameter_mm * np.sqrt(-2.0 * np.log1p(-u[:, 0]))
        else:
            r = 0.5 * self.diameter_mm * np.sqrt(u[:, 0])
        pts = self.center_mm + (r * np.cos(phi))[:, None] * eu + (r * np.sin(phi))[:, None] * ev
        if self.divergence_mrad > 0:
            from scipy.special import ndtri

            alpha = 1e-3 * self.divergence_mrad * ndtri(np.clip(u[:, 2], 1e-15, 1.0 - 1e-15))
            d = np.cos(alpha)[:, None] * d0 + np.sin(alpha)[:, None] * eu
        else:
            d = np.broadcast_to(d0, pts.shape).copy()
        return pts - self.standoff_mm * d, d


# ------------------------------------------------------------------ geometry


def reflectometer_params(config: RigConfig = NOMINAL, twin: TwinConfig = DEFAULT_TWIN):
    """The :class:`geometry.parts.reflectometer.ReflectometerParams` of a rig and twin configuration."""
    from geometry.parts.reflectometer import ReflectometerParams

    m = twin.detector_margin_mm
    plate = max(25.0, 2.0 * max(config.slit_width_mm, config.slit_height_mm) + 10.0)
    holder = max(config.sample_width_mm, twin.sample_height_mm) + 4.6
    return ReflectometerParams(
        arm_mm=config.arm_mm, slit_width_mm=config.slit_width_mm, slit_height_mm=config.slit_height_mm,
        slit_plate_width_mm=plate, slit_plate_height_mm=plate,
        slit_plate_thickness_mm=twin.slit_plate_thickness_mm, detector_gap_mm=twin.detector_gap_mm,
        detector_width_mm=config.slit_width_mm + 2 * m, detector_height_mm=config.slit_height_mm + 2 * m,
        sample_width_mm=config.sample_width_mm, sample_height_mm=twin.sample_height_mm,
        holder_width_mm=holder, holder_height_mm=holder,
    )


@lru_cache(maxsize=16)
def _home_parts(params, tolerance_mm: float) -> dict:
    """Tessellated parts at theta_i = theta_r = 0 (sample normal and arm along +z), read-only."""
    from geometry.mesh import Part
    from geometry.parts.reflectometer import build_reflectometer
    from geometry.tessellate import tessellate_parts

    try:
        scene = tessellate_parts(build_reflectometer(0.0, 0.0, 0.0, params), tolerance_mm=tolerance_mm)
    except ValueError as exc:
        raise TwinError(f"rig geometry: {exc}") from None
    out = {}
    # The detector sheet is built here, not taken from the CAD: a flat rectangle needs no CAD, and
    # geometry.parts.detector.rectangular_detector swaps width and height once placed (reported).
    z = params.arm_mm + params.slit_plate_thickness_mm + params.detector_gap_mm
    hx, hy = params.detector_width_mm / 2, params.detector_height_mm / 2
    sheet = (np.array([[-hx, -hy, z], [hx, -hy, z], [hx, hy, z], [-hx, hy, z]]), np.array([[0, 2, 1], [0, 3, 2]]))
    for part in scene.parts:
        if part.name == "detector":
            part = Part("detector", *sheet, role="detector")  # normal -z: toward the sample
        v = part.vertices_mm.copy()
        f = part.faces.copy()
        v.flags.writeable = False
        f.flags.writeable = False
        out[part.name] = (v, f)
    return out


def arm_angle(theta_i: float, theta_r: float, phi_r: float, config: RigConfig = NOMINAL) -> float:
    """Lab angle (radians, from +z toward +x) of the arm; phi_r is 0 or pi (in-plane arm)."""
    side = 1.0 if math.cos(phi_r) > 0 else -1.0
    return theta_i + side * theta_r + math.radians(config.arm_offset_deg)


def build_twin_scene(theta_i: float, theta_r: float, phi_r: float = 0.0, config: RigConfig = NOMINAL,
                     twin: TwinConfig = DEFAULT_TWIN, sample_role: str = "surface"):
    """The rig's :class:`geometry.Scene` at one set-point (angles in radians, phi_r 0 or pi).

    Parts: "sample" (material name "sample", role ``sample_role``), "holder" and
    "holder_post" (absorbers, or material "black" if ``twin.holder_rd`` > 0), "slit_plate"
    (absorber), "detector" (role detector, sensitive side toward the sample).
    """
    from geometry.mesh import Part, Scene

    if not np.isclose(abs(math.cos(phi_r)), 1.0):
        raise TwinError(f"phi_r_deg must be 0 or 180 (the arm orbits in the plane of incidence), "
                        f"got {math.degrees(phi_r):g}")
    home = _home_parts(reflectometer_params(config, twin), float(twin.tolerance_mm))
    m_sample = matrix_about_y(theta_i + math.radians(config.stage_offset_deg)) @ matrix_about_x(-math.radians(config.sample_tilt_deg))
    m_arm = matrix_about_y(arm_angle(theta_i, theta_r, phi_r, config))
    black_role = "surface" if twin.holder_rd > 0 else "absorber"
    tags = {"sample": ("sample", sample_role), "holder": ("black", black_role),
            "holder_post": ("black", black_role), "slit_plate": (None, "absorber"), "detector": (None, "detector")}
    parts = []
    for name in SAMPLE_GROUP + ARM_GROUP:
        v, f = home[name]
        rot = m_sample if name in SAMPLE_GROUP else m_arm
        material, role = tags[name]
        parts.append(Part(name, v @ rot.T, f, material if role == "surface" else None, role))
    return Scene(tuple(parts))


def laser_beam(config: RigConfig = NOMINAL, twin: TwinConfig = DEFAULT_TWIN, power_w: float = 1.0) -> LaserBeam:
    """The rig's fixed laser: along -z onto the rotation axis, waist at the sample, starting beyond the arm."""
    return LaserBeam(center_mm=np.zeros(3), direction=np.array([0.0, 0.0, -1.0]), axis_u=np.array([1.0, 0.0, 0.0]),
                     diameter_mm=config.beam_diameter_mm, profile=twin.beam_profile,
                     divergence_mrad=config.beam_divergence_mrad,
                     standoff_mm=twin.source_standoff_mm or 1.25 * config.arm_mm + 10.0,
                     power_w=power_w)


# ------------------------------------------------------------------ tracing


@dataclass(frozen=True)
class TwinPoint:
    """One traced set-point (angles in degrees, BRDF in 1/sr)."""

    theta_i_deg: float
    theta_r_deg: float
    phi_r_deg: float
    polarization: str
    brdf_per_sr: float
    stderr_per_sr: float
    detector_w: float
    detector_stderr_w: float
    n_rays: int
    seed: int
    estimator: str
    incident_w: float = 1.0  # power reaching the sample (after the polarization optics, if any)


def point_seed(seed: int, theta_i_deg: float, theta_r_deg: float, phi_r_deg: float, polarization: str) -> int:
    """Seed of one set-point: a hash of the scan seed and the set-point (micro-degree resolution)."""
    key = [int(seed)] + [int(round(a * 1e6)) % (2**32) for a in (theta_i_deg, theta_r_deg, phi_r_deg)]
    key.append(POLARIZATIONS.index(polarization))
    return int(np.random.SeedSequence(key).generate_state(1, dtype=np.uint64)[0] >> np.uint64(1))


def _trace_detector(scene, beam, n_rays, seed, materials, options):
    from straylight.trace import trace

    res = trace(scene, beam, n_rays, seed=seed, materials=materials, options=options)
    tally = res.detectors["detector"]
    return tally.power_w, tally.stderr_w


def twin_point(material, theta_i_deg: float, theta_r_deg: float, phi_r_deg: float = 0.0, polarization: str = "u",
               config: RigConfig = NOMINAL, twin: TwinConfig = DEFAULT_TWIN, n_rays: int = 20_000,
               seed: int = 0, optics=None) -> TwinPoint:
    """Trace one set-point and return the rig's reading (PHYSICS §4) with its standard error.

    Parameters
    ----------
    material : Brdf (materials.base protocol) or :class:`Mirror`.
    theta_i_deg, theta_r_deg, phi_r_deg : set-point, degrees. A negative ``theta_r_deg`` means the
        backscatter side (as :func:`rig.forward.predict_brdf`); ``phi_r_deg`` is 0 or 180.
    polarization : "s", "p" or "u".
    n_rays : rays traced for this set-point (the auto pilot adds ``2 * pilot_fraction`` of it).
    seed : scan seed; the set-point's own seed is :func:`point_seed`.
    optics : :class:`rig.beam_optics.BeamOptics` (HWP, PBS as Mueller elements on the laser's
        Stokes vector) or None. With optics, ``polarization`` must be "u": the beam that leaves
        the optics is traced with per-ray polarization (its linear part as a linearly polarized
        source, an unpolarized remainder apart), and the reading is normalised to the power that
        reaches the sample (``TwinPoint.incident_w``; ``detector_w`` is per watt of laser).
    """
    from straylight.trace import EstimatorOptions, OutputOptions, PhysicsOptions, TraceOptions

    if polarization not in POLARIZATIONS:
        raise TwinError(f"polarization must be s, p or u, got {polarization!r}")
    if isinstance(n_rays, bool) or not isinstance(n_rays, (int, np.integer)) or n_rays < 1:
        raise TwinError(f"n_rays must be a positive integer, got {n_rays!r}")
    for name, value, hi in (("theta_i_deg", theta_i_deg, 90.0), ("theta_r_deg", theta_r_deg, 90.0)):
        if not (math.isfinite(value) and abs(value) < hi):
            raise TwinError(f"{name} must be within (-90, 90) deg, got {value!r}")
    phi_r = math.radians(phi_r_deg) + (math.pi if theta_r_deg < 0 else 0.0)
    theta_i, theta_r = math.radians(theta_i_deg), math.radians(abs(theta_r_deg))
    mirror = isinstance(material, Mirror)
    scene = build_twin_scene(theta_i, theta_r, phi_r, config, twin, "mirror" if mirror else "surface")
    beam = laser_beam(config, twin)
    materials = {"sample": material} if not mirror else {}
    if twin.holder_rd > 0:
        from materials.lambertian import Lambertian

        materials["black"] = Lambertian(twin.holder_rd)
    output = OutputOptions(detector_sides="front")
    physics = PhysicsOptions(polarization=polarization,
                             mirror_reflectance=float(material.reflectance) if mirror else 1.0)
    s = point_seed(seed, theta_i_deg, theta_r_deg, phi_r_deg, polarization)
    beams = [(beam, None)]
    incident = beam.power_w
    if optics is not None:
        beams, incident = _beams_after_optics(beam, optics, polarization)
    estimator = twin.estimator
    if mirror:
        estimator = "walk"  # no scatter vertex: NEE has nothing to do
    elif estimator == "auto":
        n_pilot = max(2000, int(round(twin.pilot_fraction * n_rays)))
        pilot_seed = point_seed(s, 0.0, 0.0, 0.0, "u")  # an independent stream
        pilot_err = {}
        for est in ("nee", "walk"):
            _, err = _trace_detector(scene, beam, n_pilot, pilot_seed, materials, TraceOptions(
                estimator=EstimatorOptions(nee=est == "nee"), output=output, physics=physics))
            pilot_err[est] = err
        # a pilot that saw nothing says nothing: prefer NEE, which sees every scatter vertex
        estimator = "walk" if 0 < pilot_err["walk"] < pilot_err["nee"] else "nee"
    power, var = 0.0, 0.0
    for k, (b, _) in enumerate(beams):
        if incident <= 0:
            break
        p, e = _trace_detector(scene, b, n_rays, s if k == 0 else point_seed(s, float(k), 0.0, 0.0, "u"), materials,
                               TraceOptions(estimator=EstimatorOptions(nee=estimator == "nee"), output=output,
                                            physics=physics))
        power, var = power + p, var + e * e
    err = math.sqrt(var)
    scale = 1.0 / (incident * config.solid_angle_sr * math.cos(theta_r)) if incident > 0 else 0.0
    return TwinPoint(float(theta_i_deg), float(theta_r_deg), float(phi_r_deg), polarization, power * scale,
                     err * scale, power, err, int(n_rays), int(s), estimator, float(incident))


def _beams_after_optics(beam, optics, polarization):
    """The laser ``beam`` through ``optics``: ([(beam part, e_field or None), ...], power at the sample)."""
    import dataclasses

    from rig.beam_optics import beam_parts
    from straylight.polarization import SourcePolarization, attach

    if polarization != "u":
        raise TwinError(f"give the polarization either as optics or as polarization = s/p, not both "
                        f"(got polarization={polarization!r} with optics)")
    S = optics.stokes() * beam.power_w
    out = []
    for power, e in beam_parts(S):
        b = dataclasses.replace(beam, power_w=float(power))
        if e is not None:
            attach(b, SourcePolarization("linear", tuple(float(x) for x in e)))
        out.append((b, e))
    return out, float(S[0])


@dataclass(frozen=True)
class TwinScan:
    """A traced scan: arrays of equal length (degrees, 1/sr); ``model_per_sr`` is the fast model's
    reading at the same set-points (NaN for a mirror)."""

    theta_i_deg: np.ndarray
    theta_r_deg: np.ndarray
    phi_r_deg: np.ndarray
    polarization: np.ndarray
    brdf_per_sr: np.ndarray
    stderr_per_sr: np.ndarray
    model_per_sr: np.ndarray
    estimator: np.ndarray
    n_rays: int
    seed: int
    points: tuple = field(repr=False, default=())

    def to_json_dict(self) -> dict:
        """Plain lists, one entry per set-point."""
        z = (self.model_per_sr - self.brdf_per_sr) / np.where(self.stderr_per_sr > 0, self.stderr_per_sr, np.nan)
        return {
            "n_rays_per_point": self.n_rays, "seed": self.seed,
            "points": [
                {"theta_i_deg": float(a), "theta_r_deg": float(b), "phi_r_deg": float(c), "polarization": str(p),
                 "twin_brdf_per_sr": float(t), "twin_stderr_per_sr": float(e),
                 "model_brdf_per_sr": None if not np.isfinite(m) else float(m),
                 "z_model_minus_twin": None if not np.isfinite(zz) else float(zz), "estimator": str(k)}
                for a, b, c, p, t, e, m, zz, k in zip(self.theta_i_deg, self.theta_r_deg, self.phi_r_deg,
                                                      self.polarization, self.brdf_per_sr, self.stderr_per_sr,
                                                      self.model_per_sr, z, self.estimator)
            ],
        }


def twin_scan(material, theta_i_deg, theta_r_deg, polarization="u", config: RigConfig = NOMINAL,
              twin: TwinConfig = DEFAULT_TWIN, n_rays: int = 20_000, seed: int = 0, phi_r_deg=0.0,
              progress: bool = False) -> TwinScan:
    """Trace a scan: every ``theta_r_deg`` at every ``theta_i_deg`` for every polarization.

    Parameters
    ----------
    material : Brdf or :class:`Mirror`
    theta_i_deg, theta_r_deg : sequences of set-points, degrees (negative theta_r: backscatter side);
        ``theta_r_deg`` may also be a dict {theta_i_deg: sequence} for a different list per incidence.
    polarization : "s", "p", "u" or a sequence of them.
    n_rays, seed : per set-point (see :func:`twin_point`).
    progress : tqdm bar over set-points (stderr).

    Returns
    -------
    TwinScan, with the fast model (:func:`rig.forward.predict_brdf`) at the same set-points.
    """
    pols = [polarization] if isinstance(polarization, str) else list(polarization)
    grid = []
    for ti in np.atleast_1d(np.asarray(theta_i_deg, float)):
        trs = theta_r_deg.get(float(ti), theta_r_deg.get(ti)) if isinstance(theta_r_deg, dict) else theta_r_deg
        if trs is None:
            raise TwinError(f"theta_r_deg: no viewing angles given for theta_i_deg = {ti:g}")
        for pol in pols:
            for tr in np.atleast_1d(np.asarray(trs, float)):
                grid.append((float(ti), float(tr), pol))
    if not grid:
        raise TwinError("the scan has no set-points")
    bar = None
    if progress:
        from straylight.progress import progress_bar

        bar = progress_bar(total=len(grid), unit="point", desc="twin")
    points = []
    for ti, tr, pol in grid:
        points.append(twin_point(material, ti, tr, phi_r_deg, pol, config, twin, n_rays, seed))
        if bar is not None:
            bar.update(1)
    if bar is not None:
        bar.close()
    ti, tr, pol = (np.array(x) for x in zip(*grid))
    if isinstance(material, Mirror):
        model = np.full(len(grid), np.nan)
    else:
        from rig.forward import predict_brdf

        model = np.asarray(predict_brdf(material, ti, tr, phi_r_deg, pol, config), float)
    return TwinScan(
        theta_i_deg=ti, theta_r_deg=tr, phi_r_deg=np.full(len(grid), float(phi_r_deg)), polarization=pol,
        brdf_per_sr=np.array([p.brdf_per_sr for p in points]), stderr_per_sr=np.array([p.stderr_per_sr for p in points]),
        model_per_sr=model, estimator=np.array([p.estimator for p in points]), n_rays=int(n_rays), seed=int(seed),
        points=tuple(points),
    )


def plot_twin_scan(scan: TwinScan, material, config: RigConfig, path, title: str | None = None):
    """Seed paper Fig. 7 style: log10 BRDF vs theta_r, twin points with 1-sigma error bars over the
    fast model's curve (:func:`rig.forward.predict_brdf` on a fine grid), one colour per
    (theta_i, polarization). Writes ``path`` (PNG) and returns the matplotlib Figure."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 5.0), dpi=120)
    mirror = isinstance(material, Mirror)
    groups = sorted({(float(a), str(p)) for a, p in zip(scan.theta_i_deg, scan.polarization)})
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for k, (ti, pol) in enumerate(groups):
        c = colours[k % len(colours)]
        sel = (scan.theta_i_deg == ti) & (scan.polarization == pol)
        tr = scan.theta_r_deg[sel]
        label = f"theta_i = {ti:g} deg, {pol}"
        if not mirror:
            lo, hi = max(tr.min() - 0.5, -89.9), min(tr.max() + 0.5, 89.9)
            grid = np.union1d(np.linspace(lo, hi, 600), tr)
            if lo < ti < hi:
                grid = np.union1d(grid, ti + np.linspace(-0.6, 0.6, 121))
            grid = grid[(grid >= lo) & (grid <= hi)]
            from rig.forward import predict_brdf

            curve = np.asarray(predict_brdf(material, ti, grid, scan.phi_r_deg[0], pol, config), float)
            ax.plot(grid, curve, "-", color=c, lw=1.0, label=f"fast model, {label}")
        y = scan.brdf_per_sr[sel]
        e = scan.stderr_per_sr[sel]
        pos = y > 0
        lower = np.minimum(e[pos], 0.999 * y[pos])
        ax.errorbar(tr[pos], y[pos], yerr=[lower, e[pos]], fmt="o", ms=4, color=c, mfc="none", capsize=2,
                    label=f"twin, {label}")
    ax.set_yscale("log")
    ax.set_xlabel("theta_r (deg; negative: backscatter side)")
    ax.set_ylabel("measured BRDF (1/sr)")
    ax.set_title(title or "ray-traced twin vs fast model")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    atomicio.write_figure(fig, path)
    plt.close(fig)
    return fig
