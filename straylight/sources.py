"""Virtual light sources (they never block rays), lengths in mm, power in W.

Every source maps uniforms ``u : (n, 4)`` to ray origins and unit directions with
``emit(u) -> (origins (n, 3), dirs (n, 3))``; the tracer gives each ray the weight
``total power / n_rays``. Keys of :func:`source_from_dict` follow CONTRACTS §6.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from materials.sampling import lazy_njit


class SourceError(ValueError):
    """A source definition that cannot be used; the message names the key."""


def _vec(name, value, owner, unit=False) -> np.ndarray:
    try:
        v = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise SourceError(f"{owner}: {name} must be 3 numbers, got {value!r}") from None
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise SourceError(f"{owner}: {name} must be 3 finite numbers, got {value!r}")
    if unit:
        length = np.linalg.norm(v)
        if length == 0:
            raise SourceError(f"{owner}: {name} must not be the zero vector")
        v = v / length
    return v


def _positive(name, value, owner, allow_zero=False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise SourceError(f"{owner}: {name} must be a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        raise SourceError(f"{owner}: {name} must be {'>= 0' if allow_zero else '> 0'}, got {value!r}")
    if name == "power_w" and v > MAX_POWER_W:
        raise SourceError(f"{owner}: power_w = {v:g} W is above the {MAX_POWER_W:g} W a source may carry (the Sun "
                          f"emits 3.8e26 W; sums of ray powers would overflow to NaN); results scale with power_w")
    return v


MAX_POWER_W = 1e30  # above the Sun's 3.8e26 W; 1e308 W overflowed the tallies to NaN


MIN_RADIUS_MM = 1e-6  # a disk source smaller than 1 nm: its area (and the irradiance it divides) is not usable


def _disk_radius(value, owner) -> float:
    """A disk source's ``radius_mm``: positive, finite, and at least :data:`MIN_RADIUS_MM` (a radius
    like 1e-300 squares to 0 and its irradiance divides by zero; a point-like source is ``point``)."""
    r = _positive("radius_mm", value, owner)
    if r < MIN_RADIUS_MM:
        raise SourceError(f"{owner}: radius_mm {r:g} is below {MIN_RADIUS_MM:g} mm: a disk that small has no usable "
                          f"area; for a point-like source use type = \"point\"")
    from geometry.limits import coordinate_limit_message

    message = coordinate_limit_message(r, "radius_mm")
    if message:
        raise SourceError(f"{owner}: {message}")
    return r


def orthonormal_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tangents (t, b) with (t, b, n) right-handed, for unit n : (..., 3) (Duff et al. 2017)."""
    n = np.asarray(n, dtype=np.float64)
    x, y, z = n[..., 0], n[..., 1], n[..., 2]
    sign = np.where(z >= 0, 1.0, -1.0)
    a = -1.0 / (sign + z)
    b = x * y * a
    t = np.stack([1.0 + sign * x * x * a, sign * b, -sign * x], axis=-1)
    bb = np.stack([b, sign + y * y * a, -y], axis=-1)
    return t, bb


_TWO_PI = 2.0 * np.pi


def _check_wavelength(source, owner) -> None:
    """``wavelength_nm``: None (not given) or a positive number (CONTRACTS §6.5)."""
    if source.wavelength_nm is not None:
        object.__setattr__(source, "wavelength_nm", _positive("wavelength_nm", source.wavelength_nm, owner))


def _disk_points_loop(center, t, b, radius, u, c0, c1, out):
    """``center + (r cos phi) t + (r sin phi) b`` with ``r = radius sqrt(u[:, c0])``,
    ``phi = 2 pi u[:, c1]``, one pass per point (same operation order as the numpy form)."""
    for i in range(u.shape[0]):
        r = radius * math.sqrt(u[i, c0])
        phi = _TWO_PI * u[i, c1]
        rc = r * math.cos(phi)
        rs = r * math.sin(phi)
        for k in range(3):
            out[i, k] = (center[k] + rc * t[k]) + rs * b[k]
    return out


def _collimated_loop(center, t, b, radius, direction, u, o, d):
    """:func:`_disk_points_loop` on columns 0, 1 of u, and every direction set to ``direction``."""
    for i in range(u.shape[0]):
        r = radius * math.sqrt(u[i, 0])
        phi = _TWO_PI * u[i, 1]
        rc = r * math.cos(phi)
        rs = r * math.sin(phi)
        for k in range(3):
            o[i, k] = (center[k] + rc * t[k]) + rs * b[k]
            d[i, k] = direction[k]


def _disk_points(center, normal, radius, u, c0=0, c1=1):
    """Uniform points on a disk from the uniform columns ``u[:, c0]`` (radius) and ``u[:, c1]`` (azimuth)."""
    t, b = orthonormal_basis(normal)
    u = np.asarray(u, dtype=np.float64)
    out = np.empty((len(u), 3))
    return lazy_njit(_disk_points_loop)(center, t, b, float(radius), u, c0, c1, out)


def _cone_dirs(axis, cos_max, u0, u1):
    """Uniform in solid angle within angle acos(cos_max) of axis."""
    t, b = orthonormal_basis(axis)
    cos_t = 1.0 - u0 * (1.0 - cos_max)
    sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t * cos_t))
    phi = 2.0 * np.pi * u1
    return (sin_t * np.cos(phi))[:, None] * t + (sin_t * np.sin(phi))[:, None] * b + cos_t[:, None] * axis


@dataclass(frozen=True, eq=False)
class CollimatedDisk:
    """Parallel rays along ``direction`` starting uniformly over a disk (centre, normal, radius).

    ``power_w`` is the power carried by all rays leaving the disk.
    """

    center_mm: np.ndarray
    normal: np.ndarray
    direction: np.ndarray
    radius_mm: float
    power_w: float = 1.0
    wavelength_nm: float | None = None  # CONTRACTS §6.5: needed when a part diffracts
    name: str | None = None  # optional, used in reports (optics import names its source "pupil")

    def __post_init__(self):
        owner = "collimated_disk source"
        _check_wavelength(self, owner)
        object.__setattr__(self, "center_mm", _vec("center_mm", self.center_mm, owner))
        object.__setattr__(self, "normal", _vec("normal", self.normal, owner, unit=True))
        object.__setattr__(self, "direction", _vec("direction", self.direction, owner, unit=True))
        object.__setattr__(self, "radius_mm", _disk_radius(self.radius_mm, owner))
        object.__setattr__(self, "power_w", _positive("power_w", self.power_w, owner, allow_zero=True))
        object.__setattr__(self, "_basis", orthonormal_basis(self.normal))

    def emit(self, u):
        u = np.ascontiguousarray(u, dtype=np.float64)  # one layout, one compiled loop (a strided view is another)
        if u.ndim != 2 or u.shape[1] < 2:
            raise SourceError(f"collimated_disk source: uniforms u must have shape (n, >= 2), got {u.shape}")
        o = np.empty((len(u), 3))
        d = np.empty((len(u), 3))
        t, b = self._basis
        lazy_njit(_collimated_loop)(self.center_mm, t, b, self.radius_mm, self.direction, u, o, d)
        return o, d

    def bounds_mm(self):
        return np.stack([self.center_mm - self.radius_mm, self.center_mm + self.radius_mm])

    def uniforms_at(self, points_mm) -> np.ndarray:
        """The first two uniforms (n, 2) whose ray :meth:`emit` starts at ``points_mm`` on the disk (the
        inverse of r = radius sqrt(u1), phi = 2 pi u2)."""
        t, b = orthonormal_basis(self.normal)  # the basis emit() uses
        rel = np.asarray(points_mm, float) - self.center_mm
        x, y = rel @ t, rel @ b
        u1 = np.clip((x * x + y * y) / self.radius_mm ** 2, 0.0, np.nextafter(1.0, 0.0))
        u2 = (np.arctan2(y, x) / (2.0 * np.pi)) % 1.0
        return np.stack([u1, u2], axis=1)


@dataclass(frozen=True, eq=False)
class LambertianDisk:
    """Uniform disk emitting a cosine (Lambertian) distribution into the ``normal`` hemisphere."""

    center_mm: np.ndarray
    normal: np.ndarray
    radius_mm: float
    power_w: float = 1.0
    wavelength_nm: float | None = None

    def __post_init__(self):
        owner = "lambertian_disk source"
        _check_wavelength(self, owner)
        object.__setattr__(self, "center_mm", _vec("center_mm", self.center_mm, owner))
        object.__setattr__(self, "normal", _vec("normal", self.normal, owner, unit=True))
        object.__setattr__(self, "radius_mm", _disk_radius(self.radius_mm, owner))
        object.__setattr__(self, "power_w", _positive("power_w", self.power_w, owner, allow_zero=True))

    def emit(self, u):
        o = _disk_points(self.center_mm, self.normal, self.radius_mm, u)
        t, b = orthonormal_basis(self.normal)
        r = np.sqrt(u[:, 2])
        phi = 2.0 * np.pi * u[:, 3]
        z = np.sqrt(np.maximum(0.0, 1.0 - r * r))
        d = (r * np.cos(phi))[:, None] * t + (r * np.sin(phi))[:, None] * b + z[:, None] * self.normal
        return o, d

    def bounds_mm(self):
        return np.stack([self.center_mm - self.radius_mm, self.center_mm + self.radius_mm])


@dataclass(frozen=True, eq=False)
class PointSource:
    """Point emitting uniformly per solid angle, into a cone of ``half_angle_deg`` about ``axis``
    (the whole sphere by default). ``power_w`` is the power into that cone."""

    position_mm: np.ndarray
    power_w: float = 1.0
    axis: np.ndarray | None = None
    half_angle_deg: float = 180.0
    wavelength_nm: float | None = None

    def __post_init__(self):
        owner = "point source"
        _check_wavelength(self, owner)
        object.__setattr__(self, "position_mm", _vec("position_mm", self.position_mm, owner))
        axis = np.array([0.0, 0.0, 1.0]) if self.axis is None else _vec("axis", self.axis, owner, unit=True)
        object.__setattr__(self, "axis", axis)
        half = _positive("half_angle_deg", self.half_angle_deg, owner)
        if half > 180.0:
            raise SourceError(f"{owner}: half_angle_deg must be in (0, 180], got {half}")
        object.__setattr__(self, "half_angle_deg", half)
        object.__setattr__(self, "power_w", _positive("power_w", self.power_w, owner, allow_zero=True))

    def emit(self, u):
        cos_max = math.cos(math.radians(self.half_angle_deg))
        d = _cone_dirs(self.axis, cos_max, u[:, 2], u[:, 3])
        return np.broadcast_to(self.position_mm, d.shape).copy(), d

    def bounds_mm(self):
        return np.stack([self.position_mm, self.position_mm])


EMISSION_THETA_REFINE = 16  # the inverse CDF of an emission table: this many linear pieces per table interval


@dataclass(frozen=True, eq=False)
class SurfaceEmission:
    """Thermal emission of one side of a part, by Kirchhoff's law (docs/thermal.md): uniform points of
    its triangles (``triangles_mm`` (k, 3, 3), ``normals`` (k, 3) the unit normals of the emitting side),
    or of its exact ``annulus`` (center_mm, unit normal of the emitting side, inner_mm, outer_mm) for an
    analytic plane part, and directions with density eps(theta) cos(theta) / (pi eps_h) about that
    normal, eps the side's directional emissivity ``eps_table`` on a uniform grid of theta over
    [0, pi/2] (linear between; eps_h its hemispherical value), so every ray carries the same power:
    ``power_w`` = pi B_band(T) A eps_h, the side's emitted band power. Not a scene-file source: the
    thermal forward estimator builds one per emitting side (straylight.thermal.engine_forward).

    ``emit(u)``: u[:, 0] picks the triangle (its remainder is the azimuth), u[:, 1:3] the point,
    u[:, 3] the polar angle by the inverse of the cumulative of eps(theta) sin(theta) cos(theta)
    (:data:`EMISSION_THETA_REFINE` pieces per table interval: the density is exact to ~1e-6)."""

    triangles_mm: np.ndarray
    normals: np.ndarray
    eps_table: np.ndarray
    power_w: float = 1.0
    annulus: tuple | None = None
    wavelength_nm: float | None = None

    def __post_init__(self):
        owner = "surface emission source"
        _check_wavelength(self, owner)
        object.__setattr__(self, "power_w", _positive("power_w", self.power_w, owner, allow_zero=True))
        eps = np.asarray(self.eps_table, dtype=np.float64)
        if eps.ndim != 1 or len(eps) < 2 or not np.all(np.isfinite(eps)) or eps.min() < 0 or eps.max() <= 0:
            raise SourceError(f"{owner}: eps_table must be >= 2 finite emissivities >= 0, not all 0")
        fine = np.linspace(0.0, np.pi / 2, (len(eps) - 1) * EMISSION_THETA_REFINE + 1)
        dens = np.interp(fine, np.linspace(0.0, np.pi / 2, len(eps)), eps) * np.sin(2 * fine)
        cdf = np.concatenate([[0.0], np.cumsum(0.5 * (dens[1:] + dens[:-1]) * np.diff(fine))])
        object.__setattr__(self, "_theta", fine)
        object.__setattr__(self, "_theta_cdf", cdf / cdf[-1])
        if self.annulus is None:
            tri = np.ascontiguousarray(self.triangles_mm, dtype=np.float64).reshape(-1, 3, 3)
            area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
            if len(tri) == 0 or not area.sum() > 0:
                raise SourceError(f"{owner}: no triangle of positive area")
            object.__setattr__(self, "triangles_mm", tri)
            object.__setattr__(self, "normals", np.asarray(self.normals, dtype=np.float64).reshape(-1, 3))
            object.__setattr__(self, "_cdf", np.cumsum(area) / area.sum())
        else:
            c, n, r0, r1 = self.annulus
            object.__setattr__(self, "annulus", (_vec("center_mm", c, owner), _vec("normal", n, owner, unit=True),
                                                 float(r0), float(r1)))

    def emit(self, u):
        n = len(u)
        if self.annulus is not None:
            c, nrm, r0, r1 = self.annulus
            t, b = orthonormal_basis(nrm)
            r = np.sqrt(r0 * r0 + u[:, 1] * (r1 * r1 - r0 * r0))
            a = 2.0 * np.pi * u[:, 2]
            o = c + (r * np.cos(a))[:, None] * t + (r * np.sin(a))[:, None] * b
            normals = np.broadcast_to(nrm, (n, 3))
            spin = u[:, 0]
        else:
            cdf = self._cdf
            k = np.minimum(np.searchsorted(cdf, u[:, 0], side="right"), len(cdf) - 1)
            lo = np.where(k > 0, cdf[np.maximum(k - 1, 0)], 0.0)
            spin = np.clip((u[:, 0] - lo) / np.maximum(cdf[k] - lo, 1e-300), 0.0, np.nextafter(1.0, 0.0))
            s = np.sqrt(u[:, 1])
            wa, wb = 1.0 - s, s * (1.0 - u[:, 2])
            tri = self.triangles_mm[k]
            o = wa[:, None] * tri[:, 0] + wb[:, None] * tri[:, 1] + (1.0 - wa - wb)[:, None] * tri[:, 2]
            normals = self.normals[k]
        theta = np.interp(u[:, 3], self._theta_cdf, self._theta)
        t, b = orthonormal_basis(normals)
        st, phi = np.sin(theta), 2.0 * np.pi * spin
        d = (st * np.cos(phi))[:, None] * t + (st * np.sin(phi))[:, None] * b + np.cos(theta)[:, None] * normals
        return np.ascontiguousarray(o), np.ascontiguousarray(d)

    def bounds_mm(self):
        if self.annulus is not None:
            c, _, _, r1 = self.annulus
            return np.stack([c - r1, c + r1])
        pts = self.triangles_mm.reshape(-1, 3)
        return np.stack([pts.min(axis=0), pts.max(axis=0)])


_KEYS = {
    "collimated_disk": ({"center_mm", "normal", "direction", "radius_mm"}, {"power_w", "wavelength_nm", "name"}),
    "lambertian_disk": ({"center_mm", "normal", "radius_mm"}, {"power_w", "wavelength_nm"}),
    "point": ({"position_mm"}, {"power_w", "axis", "half_angle_deg", "wavelength_nm"}),
}


def source_from_dict(entry: dict, where: str = "source"):
    """Build a source from its CONTRACTS §6 table; unknown/missing keys are a SourceError naming ``where``.

    A ``point`` source also accepts ``center_mm`` for its position.
    """
    if not isinstance(entry, dict) or "type" not in entry:
        raise SourceError(f"{where}: a source needs a 'type' key ({', '.join(_KEYS)})")
    kind = entry["type"]
    if kind not in _KEYS:
        raise SourceError(f"{where}: unknown source type {kind!r}; known: {', '.join(_KEYS)}")
    args = {k: v for k, v in entry.items() if k != "type"}
    if kind == "point" and "center_mm" in args and "position_mm" not in args:
        args["position_mm"] = args.pop("center_mm")
    if kind == "point" and "normal" in args and "axis" not in args:
        args["axis"] = args.pop("normal")
    required, optional = _KEYS[kind]
    missing = sorted(required - set(args))
    unknown = sorted(set(args) - required - optional)
    if missing:
        raise SourceError(f"{where}: {kind} source is missing key(s) {', '.join(missing)}")
    if unknown:
        raise SourceError(
            f"{where}: unknown key(s) {', '.join(unknown)} for a {kind} source; allowed: "
            f"{', '.join(sorted(required | optional))}"
        )
    cls = {"collimated_disk": CollimatedDisk, "lambertian_disk": LambertianDisk, "point": PointSource}[kind]
    try:
        return cls(**args)
    except SourceError as exc:
        raise SourceError(f"{where}: {exc}") from None


#: any source the engine traces
Source = CollimatedDisk | LambertianDisk | PointSource | SurfaceEmission
