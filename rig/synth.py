"""Synthetic measured-like scans, for testing the diagnosis.

The readings are computed by a *different code path* from :mod:`rig.forward`: a
quasi-Monte Carlo integration (scrambled Sobol points) over the beam's transverse
profile, its divergence, and the slit, with exact 3-D ray geometry: each beam ray is
intersected with the (possibly offset and tilted) sample plane, dropped if it lands off
the sample, and joined to a slit point; the reading is

    mean over rays of f(wi, wo) cos(theta_o) (wo . a) L^2 / |S - P|^2 / cos(theta_r)

(P the sample point, S the slit point, a the arm axis; the last factors are the slit
element's solid angle over the nominal Omega = W H / L^2). So a test in which the
diagnosis recovers an injected effect is not the forward model agreeing with itself.
Instrument effects are read from their parameters (``rig.effects`` dataclasses) and
applied here by this module's own code.

Noise follows the seed paper: each point is the mean of ``n_repeats`` (3) readings
whose relative standard deviation is 5 % at the scan's peak, rising linearly in
log10(BRDF) to 30 % four decades below (and above that); ``brdf_std_per_sr`` is the
sample standard deviation of those readings.

A plan is (theta_i_deg, theta_r_deg, polarization) arrays from :mod:`rig.points`
(:func:`rig.points.paper_plan`, :func:`rig.points.score_plan`, :func:`rig.points.compact_plan`).
The score cases below (an injected effect per catalogue entry, :func:`score_case`) are what the
diagnosis tests and ``benchmarks/diagnose_score.py`` (the catalogue sweep of docs/diagnose.md and
the CONTRACTS §4.1 speed check) run.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.stats import qmc

from materials.scan import Scan, make_scan
from rig.instrument import NOMINAL, RigConfig
from rig.points import score_plan
from rig.rotations import rotate_about_x, rotate_about_y

# ----------------------------------------------------------------------------- geometry

def _ghost_fraction(theta_i, pol, n1, transmittance, n2):
    """Power returned by the substrate under the coating, written here independently of
    rig.effects.substrate_reflection: complex Snell's law for the angles and the textbook Fresnel
    amplitudes in terms of the two angles' cosines (Hecht, Optics, §4.6), incoherent bounces."""
    s1 = np.sin(theta_i) / n1                      # sin of the angle inside the coating
    cos1 = np.sqrt(1.0 - s1 * s1)
    cos0 = np.cos(theta_i)
    cos2 = np.sqrt(1.0 - (n1 * s1 / n2) ** 2 + 0j)   # inside the silicon (complex)

    def rs(na, ca, nb, cb):
        return (na * ca - nb * cb) / (na * ca + nb * cb)

    def rp(na, ca, nb, cb):
        return (nb * ca - na * cb) / (nb * ca + na * cb)

    r = rs if pol == "s" else rp
    r01 = np.abs(r(1.0, cos0, n1, cos1)) ** 2
    r12 = np.abs(r(n1, cos1, n2, cos2)) ** 2
    a = transmittance ** (2.0 / cos1)
    return (1.0 - r01) ** 2 * r12 * a / (1.0 - r01 * r12 * a)


def _coating_n(material):
    for comp in getattr(material, "components", ()) or (material,):
        n = getattr(comp, "n", None)
        if n is not None and np.real(n) > 1.0:
            return float(np.real(n))
    return 1.5


class _Ghost:
    """Material plus the substrate's ghost lobe (own implementation; see
    rig.effects.substrate_reflection for the definition)."""

    def __init__(self, material, effect):
        self.material = material
        self.t = effect.transmittance
        self.width = math.radians(effect.lobe_width_deg)
        self.n1 = effect.coating_n if effect.coating_n is not None else _coating_n(material)
        self.n2 = complex(effect.substrate_n, effect.substrate_k)

    def brdf(self, wi, wo, pol="u"):
        theta_i = np.arccos(np.clip(wi[:, 2], -1.0, 1.0))
        if pol == "u":
            frac = 0.5 * (_ghost_fraction(theta_i, "s", self.n1, self.t, self.n2)
                          + _ghost_fraction(theta_i, "p", self.n1, self.t, self.n2))
        else:
            frac = _ghost_fraction(theta_i, pol, self.n1, self.t, self.n2)
        w = self.width * np.clip(wi[:, 2], 1e-6, None)
        r2 = (wo[:, 0] + wi[:, 0]) ** 2 + (wo[:, 1] + wi[:, 1]) ** 2
        g = frac / (2 * math.pi * w**2) * np.exp(-r2 / (2 * w**2))
        return self.material.brdf(wi, wo, pol) + np.where((wo[:, 2] > 0) & (wi[:, 2] > 0), g, 0.0)


def _truth_config(config: RigConfig, effects):
    cfg = config
    material_wrap = []
    post = []
    for e in effects:
        name = type(e).name
        if name == "angle_offset":
            cfg = cfg.replace(stage_offset_deg=cfg.stage_offset_deg + e.offset_deg)
        elif name == "arm_offset":
            cfg = cfg.replace(arm_offset_deg=cfg.arm_offset_deg + e.offset_deg)
        elif name == "sample_tilt":
            cfg = cfg.replace(sample_tilt_deg=cfg.sample_tilt_deg + e.tilt_deg)
        elif name == "detector_aperture":
            if e.width_mm is not None:
                cfg = cfg.replace(slit_width_mm=e.width_mm)
        elif name == "beam_divergence":
            cfg = cfg.replace(beam_divergence_mrad=math.hypot(cfg.beam_divergence_mrad, e.sigma_mrad))
        elif name == "footprint_overfill":
            if e.sample_width_mm is not None:
                cfg = cfg.replace(sample_width_mm=e.sample_width_mm)
        elif name == "substrate_reflection":
            if e.transmittance > 0:
                material_wrap.append(e)
        elif name in ("polarization_leakage", "stray_background", "detector_nonlinearity"):
            post.append(e)
        else:
            raise ValueError(f"effects: synth does not know effect {name!r}")
    return cfg, material_wrap, post


def mc_reading(material, theta_i_deg, theta_r_deg, polarization, config: RigConfig = NOMINAL,
               n_samples: int = 4096, seed: int = 0):
    """Quasi-Monte Carlo reading of the bare instrument (no post-processing effects).

    theta_r_deg is the signed in-plane arm angle (negative: backscatter side).
    Returns (mean, standard error) arrays, 1/sr; the error is the spread over 8
    independently scrambled Sobol sequences.
    """
    ti, tr, pol = np.broadcast_arrays(np.atleast_1d(np.asarray(theta_i_deg, float)),
                                      np.atleast_1d(np.asarray(theta_r_deg, float)),
                                      np.atleast_1d(np.asarray(polarization, str)))
    ti, tr = np.radians(ti), np.radians(tr)
    L = config.arm_mm
    sig = config.beam_sigma_mm
    d_stage = math.radians(config.stage_offset_deg)
    d_arm = math.radians(config.arm_offset_deg)
    tilt = math.radians(config.sample_tilt_deg)
    n_rep = 8
    m = max(1, n_samples // n_rep)
    from scipy.special import ndtri

    sums = np.zeros((n_rep, ti.size))
    for r in range(n_rep):
        u = qmc.Sobol(5, scramble=True, seed=np.random.default_rng([seed, r])).random(m)
        u = np.clip(u, 1e-12, 1 - 1e-12)
        t = sig * ndtri(u[:, 0])                     # beam, in plane
        yb = sig * ndtri(u[:, 1])                    # beam, out of plane
        alpha = config.beam_divergence_mrad * 1e-3 * ndtri(u[:, 2])
        s = (u[:, 3] - 0.5) * config.slit_width_mm
        h = (u[:, 4] - 0.5) * config.slit_height_mm
        for code in ("s", "p", "u"):
            sel = np.flatnonzero(pol == code)
            if sel.size == 0:
                continue
            a_i = ti[sel][:, None]
            # beam rays in the lab (= nominal sample frame): direction d, through Q
            ang = a_i + alpha[None, :]
            d = np.stack([np.sin(ang), np.zeros_like(ang), -np.cos(ang)], axis=-1)
            e_t = np.stack([np.cos(a_i) + 0 * t, 0 * t + 0 * a_i, np.sin(a_i) + 0 * t], axis=-1)
            q = e_t * t[None, :, None] + np.array([0.0, 1.0, 0.0]) * yb[None, :, None]
            # true sample frame axes in the lab: nominal axes turned by the stage offset, then tilted
            ex = rotate_about_y(rotate_about_x(np.array([1.0, 0.0, 0.0]), 0.0), d_stage)
            nz = rotate_about_y(rotate_about_x(np.array([0.0, 0.0, 1.0]), -tilt), d_stage)
            ey = np.cross(nz, ex)
            lam = -(q @ nz) / (d @ nz)
            p = q + lam[..., None] * d
            on = np.abs(p @ ex) <= 0.5 * config.sample_width_mm
            # arm and slit
            a_arm = tr[sel] + d_arm
            arm = np.stack([np.sin(a_arm), np.zeros_like(a_arm), np.cos(a_arm)], axis=-1)[:, None, :]
            e_th = np.stack([np.cos(a_arm), np.zeros_like(a_arm), -np.sin(a_arm)], axis=-1)[:, None, :]
            slit = L * arm + s[None, :, None] * e_th + h[None, :, None] * np.array([0.0, 1.0, 0.0])
            ray = slit - p
            dist = np.linalg.norm(ray, axis=-1)
            wo_lab = ray / dist[..., None]
            wi_lab = -d
            to_true = np.stack([ex, ey, nz])  # rows: true axes
            wi = wi_lab @ to_true.T
            wo = wo_lab @ to_true.T
            f = np.asarray(material.brdf(wi.reshape(-1, 3), wo.reshape(-1, 3), code)).reshape(wi.shape[:2])
            cos_o = np.clip(wo[..., 2], 0.0, None)
            obliq = np.einsum("nmk,nmk->nm", wo_lab, np.broadcast_to(arm, wo_lab.shape))
            val = f * cos_o * obliq * (L / dist) ** 2 * on
            sums[r, sel] = val.mean(axis=1) / np.clip(np.cos(tr[sel]), 1e-9, None)
    mean = sums.mean(axis=0)
    stderr = sums.std(axis=0, ddof=1) / math.sqrt(n_rep)
    return mean, stderr


def _post(effects, values, ti, tr, pol, clean_other):
    out = values
    for e in effects:
        name = type(e).name
        cos_r = np.clip(np.cos(np.radians(tr)), 1e-6, None)
        if name == "polarization_leakage":
            out = np.where(pol == "u", out, (1 - e.fraction) * out + e.fraction * clean_other)
        elif name == "stray_background":
            out = out + e.level_per_sr / cos_r
        elif name == "detector_nonlinearity":
            if math.isfinite(e.saturation_per_sr):
                x = out * cos_r
                out = x / (1 + x / e.saturation_per_sr) / cos_r
    return out


def relative_noise(brdf, peak):
    """Relative std of one reading: 5 % at ``peak``, +25 % per 4 decades below it, max 30 %."""
    decades = np.log10(np.maximum(peak, 1e-300) / np.maximum(brdf, 1e-300))
    return np.clip(0.05 + 0.25 * decades / 4.0, 0.05, 0.30)


def synth_scan(material, plan, effects=(), config: RigConfig = NOMINAL, seed: int = 0,
               n_repeats: int = 3, noise: bool = True, n_samples: int = 4096,
               wavelength_nm: float | None = None, sample: str = "synthetic") -> Scan:
    """A measured-like :class:`materials.scan.Scan` of ``material`` on a rig with ``effects``.

    Parameters
    ----------
    material : Brdf protocol object (the truth).
    plan : (theta_i_deg, theta_r_deg signed, polarization) arrays, e.g. :func:`paper_plan`.
    effects : rig.effects instances describing the *true* rig (their parameters are read
        here; the effect code itself is not used).
    config : the nominal rig written to the file's metadata (the truth is config + effects).
    seed : the same seed gives the same scan.
    noise : False gives the exact (QMC) readings with std 0.
    """
    ti, tr, pol = (np.asarray(a) for a in plan)
    cfg, ghosts, post = _truth_config(config, effects)
    mat = material
    for ghost in ghosts:
        mat = _Ghost(mat, ghost)
    clean, _ = mc_reading(mat, ti, tr, pol, cfg, n_samples=n_samples, seed=seed)
    other = None
    if any(type(e).name == "polarization_leakage" for e in post):
        swap = np.where(pol == "s", "p", np.where(pol == "p", "s", pol))
        other, _ = mc_reading(mat, ti, tr, swap, cfg, n_samples=n_samples, seed=seed)
    true = _post(post, clean, ti, tr, pol, other)
    rng = np.random.default_rng([seed, 7])
    if noise:
        peak = np.zeros_like(true)
        for t in np.unique(ti):
            for p in np.unique(pol):
                sel = (ti == t) & (pol == p)
                if sel.any():
                    peak[sel] = true[sel].max()
        rel = relative_noise(true, peak)
        readings = true[:, None] * (1.0 + rel[:, None] * rng.standard_normal((true.size, n_repeats)))
        mean = readings.mean(axis=1)
        std = readings.std(axis=1, ddof=1) if n_repeats > 1 else np.full(true.size, np.nan)
    else:
        mean, std = true, np.zeros_like(true)
    lam = wavelength_nm if wavelength_nm is not None else getattr(material, "wavelength_nm", None) or config.wavelength_nm
    metadata = {"sample": sample, **config.to_metadata(), "synthetic": "rig.synth (QMC over beam and slit)"}
    return make_scan(wavelength_nm=lam, polarization=pol, theta_i_deg=ti, theta_r_deg=np.abs(tr),
                     phi_r_deg=np.where(tr < 0, 180.0, 0.0), brdf_per_sr=mean, brdf_std_per_sr=std, n_repeats=n_repeats,
                     metadata=metadata)


# ----------------------------------------------------------------------------- score cases

def glossy_black(wavelength_nm: float = 532.0):
    """Test sample like the seed paper's Z302 sample B: Lambertian rd 0.02, a sharp lobe
    (sigma 5 nm, lc 40 um, s 2.4) narrower than the rig's ~0.5 deg response, and a broad lobe
    (sigma 25 nm, lc 1.5 um, s 3), one index n = 1.52 for s and p."""
    from materials.composite import Composite
    from materials.kcorrelation import KCorrelation
    from materials.lambertian import Lambertian

    return Composite((Lambertian(0.02),
                      KCorrelation(sigma_nm=5.0, lc_um=40.0, s=2.4, n=1.52, wavelength_nm=wavelength_nm),
                      KCorrelation(sigma_nm=25.0, lc_um=1.5, s=3.0, n=1.52, wavelength_nm=wavelength_nm)))


#: One injected effect per catalogue entry, at a strength a hand-aligned reflectometer can have
#: and that leaves a held-out gap well above the noise (reasons in docs/diagnose.md §4).
SCORE_CASES = {
    "angle_offset": {"offset_deg": 0.3},
    "arm_offset": {"offset_deg": 0.5},
    "sample_tilt": {"tilt_deg": 1.0},
    "detector_aperture": {"width_mm": 10.0},
    "beam_divergence": {"sigma_mrad": 17.0},
    "footprint_overfill": {"sample_width_mm": 4.0},
    "polarization_leakage": {"fraction": 0.07},
    "stray_background": {"level_per_sr": 2e-3},
    "detector_nonlinearity": {"saturation_per_sr": 1.0},
    "substrate_reflection": {"transmittance": 0.1, "lobe_width_deg": 1.5},
}

#: The same effects near the detection limit (held-out gap 1.1-1.7x the noise level): the
#: "detection limit" table reports whether they are still ranked first and selected.
DETECTION_LIMIT_CASES = {
    "angle_offset": {"offset_deg": 0.1},
    "arm_offset": {"offset_deg": 0.1},
    "sample_tilt": {"tilt_deg": 0.8},
    "detector_aperture": {"width_mm": 2.5},
    "beam_divergence": {"sigma_mrad": 4.0},
    "footprint_overfill": {"sample_width_mm": 4.0},
    "polarization_leakage": {"fraction": 0.02},
    "stray_background": {"level_per_sr": 3e-4},
    "detector_nonlinearity": {"saturation_per_sr": 20.0},
    "substrate_reflection": {"transmittance": 0.05, "lobe_width_deg": 1.5},
}

#: The two-effect cases (names into a strength table).
PAIRS = (("angle_offset", "stray_background"), ("sample_tilt", "polarization_leakage"))


def broad_black(wavelength_nm: float = 532.0):
    """A second truth sample unlike :func:`glossy_black`: Lambertian rd 0.05 and one broad
    K-correlation lobe (sigma 15 nm, lc 3 um, s 2.8, n 1.6) -- a matte black with a wide sheen."""
    from materials.composite import Composite
    from materials.kcorrelation import KCorrelation
    from materials.lambertian import Lambertian

    return Composite((Lambertian(0.05), KCorrelation(sigma_nm=15.0, lc_um=3.0, s=2.8, n=1.6, wavelength_nm=wavelength_nm)))


def truth_material(name: str):
    """``glossy_black``, ``broad_black`` or a materials preset (e.g. ``z302_sample_a``)."""
    if name == "glossy_black":
        return glossy_black()
    if name == "broad_black":
        return broad_black()
    from materials import load_material

    return load_material(name)


def score_case(effects: dict, seed: int = 1, n_samples: int = 1024, workers: int = 2, material=None, plan=None,
               executor=None):
    """Synthesize a scan of ``material`` (default :func:`glossy_black`) on ``plan`` (default
    :func:`rig.points.score_plan`) with ``effects`` ({name: params}) and diagnose it (on ``executor`` if
    given, else ``workers`` processes). Returns (scan, Diagnosis, json document)."""
    from rig.diagnose import diagnose, to_json
    from rig.effects import build_effect

    truth = [build_effect(n, **p) for n, p in effects.items()]
    scan = synth_scan(material if material is not None else glossy_black(), plan if plan is not None else score_plan(),
                      truth, seed=seed, n_samples=n_samples)
    d = diagnose(scan, executor=executor) if executor is not None else diagnose(scan, workers=workers)
    return scan, d, to_json(d)
