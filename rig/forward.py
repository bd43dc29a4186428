"""Forward model of the reflectometer: the BRDF a scan would read, given a material.

What the rig reports at a set-point (theta_i, theta_r) is ``P_s / (P_i Omega cos theta_r)``
(seed paper, PHYSICS §4), i.e. the material BRDF averaged over every (source point,
slit point) pair that couples light into the detector:

    measured = 1 / cos(theta_r) * E[ f(wi, wo) cos(theta_o) ]

with the expectation over

* the beam's transverse profile (Gaussian, sigma = 1/e^2 diameter / 4), whose footprint on
  the sample is stretched by 1/cos(theta_i) and truncated by the sample width (overfill
  loses that power: it is not renormalised);
* the slit (uniform over width x height at ``arm_mm``);
* the beam's in-plane angular spread (Gaussian, ``beam_divergence_mrad``), folded into the
  in-plane density (it moves the specular ray by the same angle), each node keeping the mean
  incidence tilt that reaches it (see :func:`instrument_nodes`).

A ray from sample point x to slit point (s, h) leaves along ``n + u e_theta + v e_perp``
(n: arm axis, e_theta: in-plane, e_perp: out of plane) with ``u = (s - x cos theta_r) / L``
and ``v = (h - y) / L``. So the in-plane offset u has the density of a uniform slit
convolved with the beam's footprint projected on the slit (its width is
``k = cos theta_r / cos theta_i`` times the beam's), and v that of the slit height
convolved with the beam's height. Both densities are written in closed form with
``erf`` (:func:`_box_gauss_density`), and the integral over (u, v) is a fixed product
Gauss-Legendre rule (three tiers, see CORE_RULE), vectorised over all scan points.
A mirror therefore reads the beam profile convolved with the slit: it is seen over
~(beam + slit) / arm = 8.5 mrad on the nominal rig (PHYSICS §4), not over the slit's
1 mrad.

Alignment errors of :class:`rig.instrument.RigConfig` enter as rotations: a stage
offset d rotates the sample (wi and wo in the sample frame turn by -d about the
y axis, so the specular peak moves by 2d in arm angle), an arm offset rotates the
arm axis only (the peak moves by d), a tilt rotates the sample about the x axis
(the reflected beam leaves the plane by ~2 tilt cos theta_i).

The footprint projection uses the in-plane component of the arm direction; for
out-of-plane arms (phi_r not 0 or 180 deg) the footprint's out-of-plane
projection is neglected.
"""
from __future__ import annotations

import math
from typing import Callable

import numpy as np
from scipy.special import erf

from rig.instrument import NOMINAL, RigConfig
from rig.rotations import rotate_about_x, rotate_about_y

#: Quadrature rules (in-plane u nodes, out-of-plane v nodes, sinh clustering scale in rad) for
#: three tiers of set-points: "core" (the specular ray lands inside the integration window:
#: the lobe's peak is integrated), "mid" (within FAR_DEG of specular: only its tail) and
#: "far" (plain symmetric rules: the BRDF is smooth over the ~0.5 deg response).
#: Against a 64 x 96 rule clustered at 0.05 mrad, the z302_sample_a / z302_sample_b presets
#: (sharp lobe lc 500 um, 0.17 mrad wide) and rig.synth.glossy_black read within 0.3 %.
CORE_RULE = (24, 24, 2.0e-4)
MID_RULE = (16, 16, 5.0e-3)
FAR_RULE = (6, 6, None)
FAR_DEG = 3.0
#: How many divergence sigmas the core and mid windows reach (exp(-7^2/2) = 2e-11 of the peak).
DIVERGENCE_REACH = 7.0
#: Kept for reference: the clustering scale of the core rule (lobes narrower than ~0.1 mrad,
#: e.g. lc > 1 mm at 532 nm, are not resolved).
CLUSTER_RAD = CORE_RULE[2]

_RULES = {name: (np.polynomial.legendre.leggauss(nu), np.polynomial.legendre.leggauss(nv), scale)
          for name, (nu, nv, scale) in (("core", CORE_RULE), ("mid", MID_RULE), ("far", FAR_RULE))}

#: In-plane rules of the clustered tiers when the beam diverges (1.5x the nodes).
_WIDE_RULES_U = {name: np.polynomial.legendre.leggauss(3 * rule[0] // 2) for name, rule in (("core", CORE_RULE),
                                                                                     ("mid", MID_RULE))}

POL_CODES = ("s", "p", "u")

Forward = Callable[..., np.ndarray]
"""``forward(theta_i, theta_r, phi_r, polarization, config, material) -> brdf_per_sr``:
angles (n,) radians, polarization (n,) str array, config a RigConfig."""


class ForwardError(ValueError):
    """Bad input to the forward model; the message names the parameter."""


def _phi(x):
    """Standard normal CDF."""
    return 0.5 * (1.0 + erf(x / math.sqrt(2.0)))


def _box_gauss_density(y, half_width, scale, sigma, t_max):
    """Density of ``y = s - scale * t`` with s ~ U(-half_width, half_width) and
    t ~ N(0, sigma) restricted to |t| <= t_max (mass outside is lost, not renormalised).

    All arguments broadcast; ``scale`` > 0. Returns density per unit y.
    """
    a = (-half_width - y) / scale
    b = (half_width - y) / scale
    lo = np.maximum(a, -t_max)
    hi = np.minimum(b, t_max)
    mass = np.where(hi > lo, _phi(hi / sigma) - _phi(lo / sigma), 0.0)
    return mass / (2.0 * half_width)


def _sinh_rule(rule, lo, hi, centre, scale):
    """Gauss-Legendre ``rule`` on [lo, hi] (each (n,)) mapped by y = centre + scale sinh(xi):
    nodes cluster within ~``scale`` of ``centre``. Returns nodes and weights, (n, m)."""
    x, w = rule
    a = np.arcsinh((lo - centre) / scale)
    b = np.arcsinh((hi - centre) / scale)
    half = 0.5 * (b - a)
    xi = 0.5 * (a + b)[:, None] + half[:, None] * x
    y = centre[:, None] + scale * np.sinh(xi)
    return y, half[:, None] * w * scale * np.cosh(xi)


def _as_pol_array(polarization, shape):
    pol = np.asarray(polarization, dtype=str)
    try:
        pol = np.broadcast_to(pol, shape)
    except ValueError:
        raise ForwardError(f"polarization: shape {pol.shape} does not broadcast to {shape}") from None
    bad = ~np.isin(pol, POL_CODES)
    if bad.any():
        raise ForwardError(f"polarization: unknown value {pol[bad].flat[0]!r}; expected s, p or u")
    return pol


def _arm_and_specular(theta_i, theta_r, phi_r, config):
    """Arm axis (offset applied) and the true specular ray, both in the lab frame, (n, 3)."""
    n = theta_i.shape[0]
    d_stage = math.radians(config.stage_offset_deg)
    d_arm = math.radians(config.arm_offset_deg)
    tilt = math.radians(config.sample_tilt_deg)
    st = np.sin(theta_r)
    arm = np.stack([st * np.cos(phi_r), st * np.sin(phi_r), np.cos(theta_r)], axis=-1)
    if d_arm:
        arm = rotate_about_y(arm, d_arm)
    spec = np.stack([np.sin(theta_i), np.zeros(n), np.cos(theta_i)], axis=-1)
    if tilt or d_stage:
        wi0 = np.stack([-np.sin(theta_i), np.zeros(n), np.cos(theta_i)], axis=-1)
        wi_t = rotate_about_x(rotate_about_y(wi0, -d_stage), tilt)
        spec = rotate_about_y(rotate_about_x(wi_t * np.array([-1.0, -1.0, 1.0]), -tilt), d_stage)
    return arm, spec


def node_groups(theta_i, theta_r, phi_r, config: RigConfig = NOMINAL):
    """Split n set-points into the core, mid and far tiers (see CORE_RULE) and yield
    ``(indices, wi, wo, weight)`` per non-empty tier, as :func:`instrument_nodes`."""
    arm, spec = _arm_and_specular(theta_i, theta_r, phi_r, config)
    sep = np.arccos(np.clip(np.einsum("ij,ij->i", arm, spec), -1.0, 1.0))
    cos_i = np.clip(np.cos(theta_i + math.radians(config.stage_offset_deg)), 1e-9, None)
    k = np.abs(np.cos(theta_r)) / cos_i
    t_max = 0.5 * config.sample_width_mm * cos_i
    window = (0.5 * config.slit_width_mm + k * np.minimum(t_max, 6.0 * config.beam_sigma_mm)) / config.arm_mm
    # a diverging beam carries a narrow lobe's peak out to its Gaussian tail: points within
    # DIVERGENCE_REACH sigmas of it get the clustered rules (beyond, < 1e-10 of the peak)
    window = (np.hypot(window, 0.5 * config.slit_height_mm / config.arm_mm)
              + DIVERGENCE_REACH * config.beam_divergence_mrad * 1e-3)
    core = sep <= window + 2e-3
    far = sep > math.radians(FAR_DEG)
    for name, mask in (("core", core), ("mid", ~core & ~far), ("far", far & ~core)):
        idx = np.flatnonzero(mask)
        if idx.size:
            yield (idx, *instrument_nodes(theta_i[idx], theta_r[idx], phi_r[idx], config, name))


def instrument_nodes(theta_i, theta_r, phi_r, config: RigConfig = NOMINAL, tier: str = "core"):
    """Quadrature nodes of the rig's angular response for n set-points.

    Parameters
    ----------
    theta_i, theta_r, phi_r : (n,) float64, radians (set-points).
    config : RigConfig
    tier : "core", "mid" or "far" (see CORE_RULE); "far" uses plain rules over +-3.5 sigma.

    Returns
    -------
    wi : (n, A, 1, 1, 3), or (n, A, U, 1, 3) with beam divergence; wo : (n, A, U, V, 3)
        Directions in the true sample frame (A divergence nodes, U x V slit/beam nodes; the
        slit nodes of each divergence node cluster about its own specular ray).
    weight : (n, A, U, V)
        Quadrature weights including the 1/cos(theta_r) of the rig's BRDF definition and the
        cos(theta_o) of the collected power; ``sum(weight * f)`` is the reading.
    """
    theta_i = np.asarray(theta_i, float)
    theta_r = np.asarray(theta_r, float)
    phi_r = np.asarray(phi_r, float)
    n = theta_i.shape[0]
    L = config.arm_mm
    sigma = config.beam_sigma_mm
    d_stage = math.radians(config.stage_offset_deg)
    tilt = math.radians(config.sample_tilt_deg)

    # Arm axis in the nominal sample frame (lab), rotated by the arm's zero offset, and
    # where the specular ray goes: the nodes cluster there (sinh map), so lobes down to
    # ~CLUSTER_RAD wide are resolved wherever offsets or a tilt put them.
    arm, spec = _arm_and_specular(theta_i, theta_r, phi_r, config)
    rule_u, rule_v, scale = _RULES[tier]
    if config.beam_divergence_mrad > 0 and scale is not None:
        # the in-plane window now spans the divergence's +-7 sigma: 1.5x the nodes keep the bulk
        # resolved next to the clustered peak (24 left 0.017 dex at 5 sigma off specular, 36 < 0.001)
        rule_u = _WIDE_RULES_U[tier]
    far = scale is None
    y_hat = np.array([0.0, 1.0, 0.0])
    e_perp = y_hat - arm[:, 1:2] * arm
    norm = np.linalg.norm(e_perp, axis=-1, keepdims=True)
    e_perp = np.where(norm > 1e-12, e_perp / np.maximum(norm, 1e-300), np.array([1.0, 0.0, 0.0]))
    e_theta = np.cross(e_perp, arm)

    # Footprint: true incidence, stretch 1/cos(theta_i), truncated by the sample width.
    theta_i_true = theta_i + d_stage
    cos_i = np.clip(np.cos(theta_i_true), 1e-9, None)
    x_lab = np.array([math.cos(d_stage), 0.0, -math.sin(d_stage)])  # sample x axis in the lab
    k = np.maximum(np.abs(e_theta @ x_lab) / cos_i, 1e-9)
    t_max = 0.5 * config.sample_width_mm * cos_i  # beam coordinate where the footprint leaves the sample
    half_w = 0.5 * config.slit_width_mm
    half_h = 0.5 * config.slit_height_mm
    # Quadrature ranges (mm at the slit); 6 sigma covers the Gaussian to 2e-9.
    reach = 3.5 if far else 6.0
    y_u = half_w + k * np.minimum(t_max, reach * sigma)
    y_v = np.full(n, half_h + reach * sigma)
    cos_r_nominal = np.clip(np.cos(theta_r), 1e-9, None)
    mass_u = _phi(t_max / sigma) - _phi(-t_max / sigma)
    # Beam divergence: an incidence tilted by alpha moves the specular ray (and a lobe about it)
    # by alpha in u, so it is folded into the in-plane density as a Gaussian of sigma L alpha
    # added in quadrature to the projected beam (k sigma): the nodes y' = y - L alpha then follow
    # a smooth density, with no ripple on lobes narrower than the beam (discrete incidence nodes
    # would ripple). The incidence itself is not dropped: at node y' the material sees the mean
    # incidence tilt given y' (Gaussian regression of z = L alpha on y' = y - z, with y the
    # beam x slit offset of variance s_bs^2 = (k sigma)^2 + W^2 / 12):
    #     z(y') = -y' s_d^2 / (s_d^2 + s_bs^2),  s_d = L alpha_sigma,
    # and the true ray offset y' + z(y'). What is left is the spread of alpha about that mean
    # (variance s_d^2 s_bs^2 / (s_d^2 + s_bs^2) < s_bs^2), second order in the incidence.
    z_gain = None
    if config.beam_divergence_mrad > 0:
        s_d = L * config.beam_divergence_mrad * 1e-3
        s_bs2 = (k * sigma) ** 2 + (2 * half_w) ** 2 / 12.0
        z_gain = -s_d**2 / (s_d**2 + s_bs2)  # (n,)
        y_u = half_w + np.hypot(k * np.minimum(t_max, reach * sigma), (DIVERGENCE_REACH if not far else reach) * s_d)
        k = np.hypot(k, s_d / sigma)
    alphas, p_alpha = np.zeros(1), np.ones(1)
    wi_all, wo_all, w_all = [], [], []
    for alpha, pa in zip(alphas, p_alpha):
        # each incidence direction of the diverging beam has its own specular ray: cluster there
        if alpha:
            _, spec = _arm_and_specular(theta_i + alpha, theta_r, phi_r, config)
        rel = spec - arm
        u_c = np.clip(np.einsum("ij,ij->i", rel, e_theta) * L, -y_u, y_u)
        v_c = np.clip(np.einsum("ij,ij->i", rel, e_perp) * L, -y_v, y_v)
        if far:  # smooth integrand: symmetric rules, so linear variations cancel exactly
            yu, wu = y_u[:, None] * rule_u[0], y_u[:, None] * rule_u[1]
            yv, wv = y_v[:, None] * rule_v[0], y_v[:, None] * rule_v[1]
        else:
            assert scale is not None  # only the far rule has no clustering scale
            yu, wu = _sinh_rule(rule_u, -y_u, y_u, u_c, scale * L)
            yv, wv = _sinh_rule(rule_v, -y_v, y_v, v_c, scale * L)
        pu = _box_gauss_density(yu, half_w, k[:, None], sigma, t_max[:, None]) * wu
        # Renormalise to the analytic mass (fraction of the beam on the sample): removes the
        # rule's error on the density's soft edges, so a Lambertian reads rd/pi.
        pu *= (mass_u / np.maximum(pu.sum(axis=1), 1e-300))[:, None]
        pv = _box_gauss_density(yv, half_h, 1.0, sigma, np.inf) * wv
        pv /= np.maximum(pv.sum(axis=1), 1e-300)[:, None]
        v = yv / L
        if z_gain is None:
            u = yu / L
            ang = theta_i + alpha
        else:  # mean incidence tilt z / L at each folded node, true ray offset y' + z (see above)
            z = z_gain[:, None] * yu
            u = (yu + z) / L
            ang = theta_i[:, None] + alpha + z / L  # (n, U)
        wi = np.stack([-np.sin(ang), np.zeros_like(ang), np.cos(ang)], axis=-1)
        # Lab (nominal sample frame) -> true sample frame: a rotation, applied to the (n, 3)
        # frame vectors before the (n, U, V) nodes are built from them (the norm is invariant).
        frame = (arm, e_theta, e_perp)
        if wi.ndim == 2:
            wi = wi[:, None, :]  # (n, 1 or U, 3)
        if d_stage:
            wi = rotate_about_y(wi, -d_stage)
            frame = tuple(rotate_about_y(f, -d_stage) for f in frame)
        if tilt:
            wi = rotate_about_x(wi, tilt)
            frame = tuple(rotate_about_x(f, tilt) for f in frame)
        f_arm, f_theta, f_perp = frame
        wo = (f_arm[:, None, None, :] + u[:, :, None, None] * f_theta[:, None, None, :]
              + v[:, None, :, None] * f_perp[:, None, None, :])
        # |arm + u e_theta + v e_perp|^2 = 1 + u^2 + v^2 (orthonormal frame)
        wo *= (1.0 / np.sqrt(1.0 + u[:, :, None] ** 2 + v[:, None, :] ** 2))[..., None]
        cos_o = np.clip(wo[..., 2], 0.0, None)
        w_all.append(pa * pu[:, :, None] * pv[:, None, :] * cos_o / cos_r_nominal[:, None, None])
        wi_all.append(wi)
        wo_all.append(wo)
    wi = np.stack(wi_all, axis=1)[:, :, :, None, :]  # (n, A, 1 or U, 1, 3)
    wo = np.stack(wo_all, axis=1)
    return wi, wo, np.stack(w_all, axis=1)


def instrument_forward(theta_i, theta_r, phi_r, polarization, config: RigConfig, material) -> np.ndarray:
    """The bare instrument: ``sum(weight * f)`` over :func:`instrument_nodes` (see module doc).

    ``material.brdf(wi, wo, polarization)`` is called once per polarization and node group
    (:func:`node_groups`: core, mid and far tiers with their own rules).
    Angles (n,) radians; polarization (n,) str. Returns (n,) 1/sr.
    """
    out = np.zeros(theta_i.shape[0])
    for code in POL_CODES:
        sel = np.flatnonzero(polarization == code)
        if sel.size == 0:
            continue
        for idx, wi, wo, weight in node_groups(theta_i[sel], theta_r[sel], phi_r[sel], config):
            wi_b, wo_b = np.broadcast_arrays(wi, wo)
            f = np.asarray(material.brdf(wi_b.reshape(-1, 3), wo_b.reshape(-1, 3), code), float)
            out[sel[idx]] = np.einsum("nauv,nauv->n", weight, f.reshape(weight.shape))
    return out


def compose(effects=(), base: Forward = instrument_forward) -> Forward:
    """Wrap ``base`` with each effect in order (the first is innermost)."""
    forward = base
    for effect in effects:
        forward = effect.wrap(forward)
    return forward


def predict_brdf(material, theta_i_deg, theta_r_deg, phi_r_deg=0.0, polarization="u",
                 config: RigConfig = NOMINAL, effects=()) -> np.ndarray:
    """The BRDF the reflectometer would read for ``material`` (1/sr).

    Parameters
    ----------
    material : object with ``brdf(wi, wo, polarization)`` (materials.base.Brdf protocol).
    theta_i_deg, theta_r_deg, phi_r_deg : array_like, degrees, broadcast together.
        Set-points; a negative ``theta_r_deg`` means the backscatter side (phi_r + 180).
    polarization : str or array_like of 's', 'p', 'u', broadcast with the angles.
    config : RigConfig, the rig geometry (default: the nominal rig).
    effects : sequence of instrument effects (``rig.effects``), applied in order.

    Returns
    -------
    ndarray, broadcast shape of the inputs, 1/sr.
    """
    try:
        ti, tr, pr = np.broadcast_arrays(np.asarray(theta_i_deg, float), np.asarray(theta_r_deg, float),
                                         np.asarray(phi_r_deg, float))
    except ValueError:
        raise ForwardError("theta_i_deg, theta_r_deg, phi_r_deg: shapes do not broadcast") from None
    shape = np.broadcast_shapes(ti.shape, np.shape(polarization))
    ti, tr, pr = (np.broadcast_to(a, shape) for a in (ti, tr, pr))
    pol = _as_pol_array(polarization, shape).ravel()
    for name, arr in (("theta_i_deg", ti), ("theta_r_deg", tr)):
        if not np.all(np.isfinite(arr)) or np.any(np.abs(arr) > 90.0):
            raise ForwardError(f"{name}: values must be finite and within [-90, 90] deg")
    ti = np.radians(ti.ravel())
    pr = np.radians(pr.ravel()) + np.where(tr.ravel() < 0, np.pi, 0.0)
    tr = np.radians(np.abs(tr.ravel()))
    forward = compose(effects)
    return np.asarray(forward(ti, tr, pr, pol, config, material), float).reshape(shape)
