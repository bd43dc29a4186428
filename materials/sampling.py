"""Importance-sampling helpers in the projected (beta) disk, and parameter checks.

``cos(theta_r) dOmega = d beta_x d beta_y`` (PHYSICS §3), so a density ``p_beta``
over the beta plane is a density ``p_beta cos(theta_r)`` per steradian, and the
sample weight ``f cos(theta_r) / pdf_per_sr`` equals ``f / p_beta``.

The lobe proposal is the radial profile ``(1 + r^2 / l^2)^(-s/2)`` about beta0,
r = |beta - beta0| on ``0 <= r <= Rmax`` with ``Rmax = 1 + |beta0|`` so that the
proposal covers the whole unit disk. Draws with |beta| >= 1 lie below the horizon:
they are returned with weight 0 and pdf 0 (never re-drawn, PHYSICS §3).

Helpers come in triples (STYLE §4): ``sample_*``, ``*_pdf``, ``invert_*``.
"""
from __future__ import annotations

import math
from numbers import Real

import numpy as np

from materials.base import MaterialError, Sample
from materials.jit_cache import njit
from materials.jit_start import start_numba

_S_EQUALS_2 = 1e-9  # |s - 2| below this uses the logarithmic (s = 2) branch


# ---------------------------------------------------------------- parameter checks


def check_real(owner: str, name: str, value, *, lo=None, hi=None, lo_open=False, hi_open=False) -> float:
    """Return ``float(value)`` or raise MaterialError naming ``owner.name`` and the allowed range."""
    if isinstance(value, bool) or not isinstance(value, (Real, np.floating, np.integer)):
        raise MaterialError(f"{owner}: parameter {name!r} must be a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise MaterialError(f"{owner}: parameter {name!r} must be finite, got {value!r}")
    bad = (
        (lo is not None and (v < lo or (lo_open and v == lo)))
        or (hi is not None and (v > hi or (hi_open and v == hi)))
    )
    if bad:
        left = "(" if lo_open else "["
        right = ")" if hi_open else "]"
        rng = f"{left}{'-inf' if lo is None else lo}, {'inf' if hi is None else hi}{right}"
        raise MaterialError(f"{owner}: parameter {name!r} = {v!r} is outside {rng}")
    return v


def check_index(owner: str, name: str, value) -> tuple[float, float]:
    """A refractive index given as a number or ``[n, k]`` -> (n, k) floats, checked (n > 0, k >= 0)."""
    if isinstance(value, (list, tuple)):
        if len(value) != 2:
            raise MaterialError(f"{owner}: parameter {name!r} must be a number or [n, k], got {value!r}")
        return (check_real(owner, f"{name}[0]", value[0], lo=0.0, lo_open=True),
                check_real(owner, f"{name}[1]", value[1], lo=0.0))
    return (check_real(owner, name, value, lo=0.0, lo_open=True), 0.0)


def set_fields(obj, **values) -> None:
    """Assign checked values on a frozen dataclass (used in ``__post_init__``)."""
    for key, value in values.items():
        object.__setattr__(obj, key, value)


# ---------------------------------------------------------------- uniforms


def direction_uniforms(u) -> np.ndarray:
    """The two uniforms that pick a direction: ``u[:, -2:]`` of an (n, 2) or (n, 3) array.

    The protocol passes (n, 3) uniforms; column 0 is reserved for choosing a
    component in composites (materials.base.Brdf.sample).
    """
    u = np.asarray(u, dtype=float)
    if u.ndim != 2 or u.shape[1] not in (2, 3):
        raise ValueError(f"uniforms u must have shape (n, 2) or (n, 3), got {u.shape}")
    return u[:, -2:]


# ---------------------------------------------------------------- cosine (unit disk)


_TWO_PI = 2.0 * np.pi


def _cosine_hemisphere_loop(u2, out):
    # one pass per draw, the operations of the numpy form in the same order (bit-identical)
    for i in range(u2.shape[0]):
        r = math.sqrt(u2[i, 0])
        phi = _TWO_PI * u2[i, 1]
        out[i, 0] = r * math.cos(phi)
        out[i, 1] = r * math.sin(phi)
        out[i, 2] = math.sqrt(max(0.0, 1.0 - r * r))
    return out


def _cosine_sample_loop(wi, u2, weight_above, wo, weight, pdf):
    # _cosine_hemisphere_loop plus weight and pdf (cos / pi), zero unless wi and wo are above the horizon
    for i in range(u2.shape[0]):
        r = math.sqrt(u2[i, 0])
        phi = _TWO_PI * u2[i, 1]
        wo[i, 0] = r * math.cos(phi)
        wo[i, 1] = r * math.sin(phi)
        z = math.sqrt(max(0.0, 1.0 - r * r))
        wo[i, 2] = z
        if wi[i, 2] > 0 and z > 0:
            weight[i] = weight_above
            pdf[i] = z / math.pi
        else:
            weight[i] = 0.0
            pdf[i] = 0.0


_COMPILED: dict = {}


def lazy_njit(fn, error_model: str = "python"):
    """``fn`` compiled by numba (``nogil``, cached) on first use, so numba is imported only when a
    compiled loop first runs; also used by ``straylight.sources``. ``error_model="numpy"``: a
    division by zero gives inf / nan as numpy's does, instead of raising."""
    jit = _COMPILED.get(fn)
    if jit is None:
        start_numba()  # numba's target without scipy.linalg (materials.jit_start), whoever compiles first
        jit = _COMPILED[fn] = njit(cache=True, nogil=True, error_model=error_model)(fn)
    return jit


def sample_cosine_hemisphere(u2: np.ndarray) -> np.ndarray:
    """Cosine-weighted direction: uniform in the unit beta disk. u2 : (n, 2) -> (n, 3).

    ``r = sqrt(u0)``, ``phi = 2 pi u1``, ``w = (r cos phi, r sin phi, sqrt(1 - r^2))`` (PHYSICS §3).
    """
    u2 = np.ascontiguousarray(u2, dtype=np.float64)  # one layout, one compiled loop (direction_uniforms' view is another)
    if u2.ndim != 2 or u2.shape[1] != 2:
        raise ValueError(f"uniforms u2 must have shape (n, 2), got {u2.shape}")
    return lazy_njit(_cosine_hemisphere_loop)(u2, np.empty((len(u2), 3)))


def sample_cosine_hemisphere_weighted(wi: np.ndarray, u2: np.ndarray, weight_above: float) -> Sample:
    """:func:`sample_cosine_hemisphere` draws with weight ``weight_above`` and pdf ``cos(theta_r) / pi`` per sr
    where wi and wo are above the horizon (0 elsewhere), in one pass: the sample of a constant BRDF
    ``f = weight_above / pi`` (f cos / pdf = weight_above)."""
    u2 = np.asarray(u2, dtype=np.float64)
    if u2.ndim != 2 or u2.shape[1] != 2:
        raise ValueError(f"uniforms u2 must have shape (n, 2), got {u2.shape}")
    n = len(u2)
    try:
        wi = np.broadcast_to(np.asarray(wi, dtype=np.float64), (n, 3))
    except ValueError:
        raise ValueError(f"wi must have shape (n, 3) or (1, 3) for {n} uniforms, got {np.shape(wi)}") from None
    wo, weight, pdf = np.empty((n, 3)), np.empty(n), np.empty(n)
    lazy_njit(_cosine_sample_loop)(wi, u2, float(weight_above), wo, weight, pdf)
    return Sample(wo=wo, weight=weight, pdf_per_sr=pdf)


def cosine_hemisphere_pdf(cos_theta: np.ndarray) -> np.ndarray:
    """Density per sr of :func:`sample_cosine_hemisphere`: cos(theta) / pi above the horizon."""
    cos_theta = np.asarray(cos_theta, float)
    return np.where(cos_theta > 0, cos_theta / np.pi, 0.0)


def invert_cosine_hemisphere_sample(w: np.ndarray) -> np.ndarray:
    """Uniforms (n, 2) that :func:`sample_cosine_hemisphere` maps to ``w``."""
    w = np.asarray(w, float)
    r2 = w[:, 0] ** 2 + w[:, 1] ** 2
    phi = np.mod(np.arctan2(w[:, 1], w[:, 0]), 2 * np.pi)
    return np.stack([r2, phi / (2 * np.pi)], axis=-1)


# ---------------------------------------------------------------- radial lobe about beta0


def _one_minus_s_half(s):
    return 1.0 - 0.5 * s


def radial_lobe_norm(l, s, r_max) -> np.ndarray:
    """Integral of ``(1 + r^2/l^2)^(-s/2)`` over the disk r <= r_max (PHYSICS §3).

    ``2 pi l^2 c / (s - 2)`` with ``c = 1 - (1 + r_max^2/l^2)^(1 - s/2)``;
    s = 2: ``pi l^2 ln(1 + r_max^2/l^2)``. Written with log1p/expm1 so s near 2 is stable.
    """
    if np.ndim(l) == 0 and np.ndim(s) == 0 and np.ndim(r_max) == 1:  # one lobe: its branch alone (the same bits)
        lf, a = float(l), _one_minus_s_half(float(s))
        x = np.log1p((np.asarray(r_max, float) / lf) ** 2)
        if abs(a) < 0.5 * _S_EQUALS_2:
            return np.pi * lf**2 * x
        return np.pi * lf**2 * np.expm1(a * x) / a
    l, s, r_max = np.broadcast_arrays(np.asarray(l, float), np.asarray(s, float), np.asarray(r_max, float))
    x = np.log1p((r_max / l) ** 2)
    a = _one_minus_s_half(s)
    near2 = np.abs(a) < 0.5 * _S_EQUALS_2
    a_safe = np.where(near2, 1.0, a)
    # 2 pi l^2 c / (s - 2) = pi l^2 (-expm1(a x)) / (-a) = pi l^2 expm1(a x) / a
    general = np.pi * l**2 * np.expm1(a_safe * x) / a_safe
    return np.where(near2, np.pi * l**2 * x, general)


def sample_radial_lobe(u2: np.ndarray, l, s, r_max) -> np.ndarray:
    """Offsets d = beta - beta0, (n, 2), with density ``(1 + r^2/l^2)^(-s/2) / norm`` on r <= r_max.

    Radial inverse CDF (PHYSICS §3): ``r = l sqrt((1 - u c)^(1/(1-s/2)) - 1)``,
    s = 2: ``r = l sqrt((1 + r_max^2/l^2)^u - 1)``; the azimuth is uniform.
    """
    if np.ndim(l) == 0 and np.ndim(s) == 0 and np.shape(r_max) == u2[:, 0].shape:
        # one lobe: the expressions below on its branch alone (the same bits, one expm1 fewer per draw)
        l, a = float(l), _one_minus_s_half(float(s))
        r_max = np.asarray(r_max, float)
        x = np.log1p((r_max / l) ** 2)
        if abs(a) < 0.5 * _S_EQUALS_2:
            t = np.expm1(u2[:, 0] * x)
        else:
            t = np.expm1(np.log1p(u2[:, 0] * np.expm1(a * x)) / a)
    else:
        l, s, r_max = (np.broadcast_to(np.asarray(v, float), u2[:, 0].shape) for v in (l, s, r_max))
        x = np.log1p((r_max / l) ** 2)
        a = _one_minus_s_half(s)
        near2 = np.abs(a) < 0.5 * _S_EQUALS_2
        a_safe = np.where(near2, 1.0, a)
        # (1 - u c)^(1/a) - 1 with c = -expm1(a x): exp(log1p(u expm1(a x)) / a) - 1
        general = np.expm1(np.log1p(u2[:, 0] * np.expm1(a_safe * x)) / a_safe)
        t = np.where(near2, np.expm1(u2[:, 0] * x), general)
    r = l * np.sqrt(np.maximum(t, 0.0))
    r = np.minimum(r, r_max)
    phi = 2.0 * np.pi * u2[:, 1]
    return np.stack([r * np.cos(phi), r * np.sin(phi)], axis=-1)


def radial_lobe_density(d: np.ndarray | None, l, s, r_max, pair=None) -> np.ndarray:
    """Density over the beta plane of :func:`sample_radial_lobe` at offsets d : (n, 2); with ``pair``
    (a :class:`materials.base.PairGeometry`, scalar l and s, r_max its own) d is its Bragg offset and
    the shape and the aperture test are shared with the other lobes (the same bits)."""
    if pair is not None:
        r2 = pair.r2()
        l2, s_ = np.asarray(l, float) ** 2, np.asarray(s, float)
        shape = pair.get(("shape", float(s_), float(l2)), lambda: np.exp(-0.5 * s_ * np.log1p(r2 / l2)))
        inside = pair.get("inside", lambda: r2 <= np.asarray(r_max, float) ** 2 * (1 + 1e-12))
        return np.where(inside, shape / radial_lobe_norm(l, s, r_max), 0.0)
    assert d is not None  # (the offsets are given unless a PairGeometry carries them)
    r2 = d[:, 0] ** 2 + d[:, 1] ** 2
    l = np.asarray(l, float)
    shape = np.exp(-0.5 * np.asarray(s, float) * np.log1p(r2 / l**2))
    inside = r2 <= np.asarray(r_max, float) ** 2 * (1 + 1e-12)
    return np.where(inside, shape / radial_lobe_norm(l, s, r_max), 0.0)


def invert_radial_lobe_sample(d: np.ndarray, l, s, r_max) -> np.ndarray:
    """Uniforms (n, 2) that :func:`sample_radial_lobe` maps to offsets d."""
    r2 = d[:, 0] ** 2 + d[:, 1] ** 2
    l, s, r_max = (np.broadcast_to(np.asarray(v, float), r2.shape) for v in (l, s, r_max))
    u0 = radial_lobe_norm(l, s, np.sqrt(r2)) / radial_lobe_norm(l, s, r_max)
    phi = np.mod(np.arctan2(d[:, 1], d[:, 0]), 2 * np.pi)
    return np.stack([u0, phi / (2 * np.pi)], axis=-1)


# ---------------------------------------------------------------- beta <-> direction


def beta0_of(wi: np.ndarray) -> np.ndarray:
    """Projected specular direction beta0 = -wi_xy, (n, 2)."""
    return -np.asarray(wi, float)[:, :2]


def direction_from_beta(beta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """beta (n, 2) -> (wo (n, 3), above (n,) bool). Below the horizon (|beta| >= 1)
    wo is the horizontal unit vector along beta (wo_z = 0) and ``above`` is False."""
    b2 = beta[:, 0] ** 2 + beta[:, 1] ** 2
    above = b2 < 1.0
    norm = np.where(above, 1.0, np.sqrt(np.maximum(b2, 1e-300)))
    wo = np.stack(
        [beta[:, 0] / norm, beta[:, 1] / norm, np.sqrt(np.where(above, 1.0 - b2, 0.0))], axis=-1
    )
    return wo, above


def lobe_direction(wi, u, l, s) -> np.ndarray:
    """Only the directions of :func:`lobe_sample` (for composites, which weight draws themselves). One lobe
    (scalar l, s): numpy's logarithms and exponentials of :func:`sample_radial_lobe` (their bits), the rest
    (the radius, the azimuth, :func:`direction_from_beta`) in one compiled pass (:func:`_lobe_direction_loop`,
    :func:`lobe_direction_numpy`'s operations in its order: the same bits)."""
    wi = np.asarray(wi, float)
    if np.ndim(l) != 0 or np.ndim(s) != 0 or wi.ndim != 2 or wi.shape[1] != 3:
        return lobe_direction_numpy(wi, u, l, s)
    u2 = direction_uniforms(u)
    b0 = beta0_of(wi)
    r_max = 1.0 + np.hypot(b0[:, 0], b0[:, 1])
    lf, a = float(l), _one_minus_s_half(float(s))
    x = np.log1p((r_max / lf) ** 2)  # sample_radial_lobe's one-lobe branch
    if abs(a) < 0.5 * _S_EQUALS_2:
        t = np.expm1(u2[:, 0] * x)
    else:
        t = np.expm1(np.log1p(u2[:, 0] * np.expm1(a * x)) / a)
    wo = np.empty((len(wi), 3))
    if len(wi):
        lazy_njit(_lobe_direction_loop, "numpy")(np.ascontiguousarray(wi), np.ascontiguousarray(t),
                                                 np.ascontiguousarray(r_max), np.ascontiguousarray(u2[:, 1]), lf,
                                                 2.0 * np.pi, wo)
    return wo


def _lobe_direction_loop(wi, t, r_max, u_phi, l, two_pi, wo):
    """The end of :func:`sample_radial_lobe` and :func:`direction_from_beta` row by row: ``np.maximum``,
    ``np.minimum`` (NaN kept), ``beta = -wi_xy + d``, ``|beta|^2 = bx^2 + by^2``."""
    for i in range(len(t)):
        ti = t[i]
        ti = ti if (ti >= 0.0 or ti != ti) else 0.0
        r = l * np.sqrt(ti)
        rm = r_max[i]
        r = r if (r <= rm or r != r) else rm
        phi = two_pi * u_phi[i]
        bx = -wi[i, 0] + r * np.cos(phi)
        by = -wi[i, 1] + r * np.sin(phi)
        b2 = bx * bx + by * by
        if b2 < 1.0:
            wo[i, 0] = bx / 1.0
            wo[i, 1] = by / 1.0
            wo[i, 2] = np.sqrt(1.0 - b2)
        else:
            m = b2 if (b2 >= 1e-300 or b2 != b2) else 1e-300
            norm = np.sqrt(m)
            wo[i, 0] = bx / norm
            wo[i, 1] = by / norm
            wo[i, 2] = np.sqrt(0.0)


def lobe_direction_numpy(wi, u, l, s) -> np.ndarray:
    """:func:`lobe_direction` in vectorised numpy (the reference it is tested against)."""
    wi = np.asarray(wi, float)
    b0 = beta0_of(wi)
    r_max = 1.0 + np.hypot(b0[:, 0], b0[:, 1])
    return direction_from_beta(b0 + sample_radial_lobe(direction_uniforms(u), l, s, r_max))[0]


def lobe_sample(model, wi, u, polarization, l, s) -> Sample:
    """Sample a lobe centred on beta0 with the radial proposal of width l, slope s.

    Weight ``f / p_beta`` (= f cos / pdf_per_sr), zero below the horizon.
    ``model.brdf`` supplies f; l and s may be scalars or (n,) arrays.
    """
    wi = np.asarray(wi, float)
    u2 = direction_uniforms(u)
    b0 = beta0_of(wi)
    r_max = 1.0 + np.hypot(b0[:, 0], b0[:, 1])
    d = sample_radial_lobe(u2, l, s, r_max)
    wo, above = direction_from_beta(b0 + d)
    p_beta = radial_lobe_density(d, l, s, r_max)
    f = np.zeros(len(wi))
    if np.any(above):
        f[above] = model.brdf(wi[above], wo[above], polarization)
    good = above & (p_beta > 0)
    weight = np.where(good, f / np.where(good, p_beta, 1.0), 0.0)
    pdf = np.where(good, p_beta * wo[:, 2], 0.0)
    return Sample(wo=wo, weight=weight, pdf_per_sr=pdf)


def lobe_pdf(wi, wo, l, s, pair=None) -> np.ndarray:
    """Density per sr of :func:`lobe_sample` producing wo (0 below the horizon); ``pair``: the
    :class:`materials.base.PairGeometry` of (wi, wo) a composite shares among its lobes (scalar l, s)."""
    if pair is not None and np.ndim(l) == 0 and np.ndim(s) == 0:
        def reach():
            b0 = beta0_of(pair.wi)
            return 1.0 + np.hypot(b0[:, 0], b0[:, 1])
        r_max = pair.get("r_max", reach)
        density = radial_lobe_density(None, l, s, r_max, pair)
        return np.where(pair.above(), density * pair.get("cos_r+", lambda: np.maximum(pair.wo[:, 2], 0.0)), 0.0)
    wi = np.asarray(wi, float)
    wo = np.asarray(wo, float)
    b0 = beta0_of(wi)
    r_max = 1.0 + np.hypot(b0[:, 0], b0[:, 1])
    d = wo[:, :2] - b0
    above = (wo[:, 2] > 0) & (wi[:, 2] > 0)
    return np.where(above, radial_lobe_density(d, l, s, r_max) * np.maximum(wo[:, 2], 0.0), 0.0)


def cosine_sample(model, wi, u, polarization) -> Sample:
    """Cosine-weighted proposal with weight ``f cos / pdf = pi f`` (for models without a lobe sampler)."""
    wi = np.asarray(wi, float)
    wo = sample_cosine_hemisphere(direction_uniforms(u))
    f = model.brdf(wi, wo, polarization)
    above = (wo[:, 2] > 0) & (wi[:, 2] > 0)
    return Sample(
        wo=wo,
        weight=np.where(above, np.pi * f, 0.0),
        pdf_per_sr=np.where(above, wo[:, 2] / np.pi, 0.0),
    )
