"""Analytic optical surfaces (CONTRACTS §6.1): conic, even asphere, plane, cylinder.

Each surface is meshed for the hit search (embree finds the triangle), then every hit is refined
onto the exact surface by Newton's method along the ray on the surface's implicit equation, and
the exact normal is taken there. Local frame: ``w = axis``, origin at ``vertex_mm``.

- conic: ``G = c rho^2 - 2 z + (1 + k) c z^2 = 0``, whose branch through the vertex is the sag
  ``z = h(rho) = c rho^2 / (1 + sqrt(1 - (1 + k) c^2 rho^2))`` (c = 1 / radius_mm, k = conic);
  clear aperture ``inner_radius_mm <= rho' <= outer_radius_mm``, rho' measured from the aperture's centre
  (the axis, or ``aperture_center_mm`` for an off-axis segment), within the rectangle
  ``aperture_half_widths_mm`` when one is given.
- asphere: ``G = h(rho) + sum_i A_(2i+4) rho^(2i+4) - z`` (the conic sag plus an even polynomial,
  ``coefficients = [A4, A6, ...]``); Newton along the ray on this G from the mesh hit, with
  ``dG/dt = q(rho^2) (x dx + y dy) - dz`` where ``q = h'(rho) / rho`` stays finite on the axis.
  ``power_terms = [[p, a_p], ...]`` adds ``sum a_p rho^p`` for any powers p >= 1 (a Zemax extended odd
  asphere's r^3, r^5... terms, or an r^2 term): ``q`` gains ``p a_p rho^(p - 2)``, infinite on the axis for
  p = 1 (a cone's tip; taken as 0 there, where no ray lands but by chance).
- plane: ``G = -2 z``, a disk or annulus.
- cylinder: ``G = rho^2 - R^2`` for ``0 <= z <= length_mm``; the front is the outside.

Any of them may be placed off the axis by ``tilt_deg = [ax, ay, az]`` (rotations about the world x,
then y, then z axes, about the vertex: ``axis' = Rz Ry Rx axis``) and then ``offset_mm = [dx, dy,
dz]`` (``vertex' = vertex + offset``): a decentre or a coordinate break of a lens file.

The front side is the side ``axis`` points to (conic, plane; the outside for a cylinder); front
normals are ``-grad G / |grad G|`` for conic and plane and ``+grad G / |grad G|`` for the cylinder.
G is a polynomial of degree 2 along any ray, so Newton from a mesh hit (a chord away from the
surface) converges quadratically to the nearby root: 3-5 iterations to 1e-13 mm.

References: Born & Wolf §4.10 / Malacara, *Optical Shop Testing*, app. 1 (conic sag);
W. T. Welford, *Aberrations of Optical Systems* (1986), §2 (surfaces of revolution).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from geometry.mesh import GeometryError

NEWTON_MAX_ITER = 30
NEWTON_TOL_REL = 1e-12


def _unit(v, what, where):
    a = np.asarray(v, float)
    if a.shape != (3,) or not np.all(np.isfinite(a)) or np.linalg.norm(a) == 0:
        raise GeometryError(f"{where}: {what} must be a non-zero [x, y, z], got {v!r}")
    return a / np.linalg.norm(a)


def _frame(w):
    """Orthonormal (u, v, w) with w the axis (u: the world axis least aligned with w, made normal)."""
    helper = np.eye(3)[int(np.argmin(np.abs(w)))]
    u = helper - np.dot(helper, w) * w
    u /= np.linalg.norm(u)
    return u, np.cross(w, u), w


@dataclass(frozen=True, eq=False)
class _Surface:
    vertex_mm: np.ndarray
    axis: np.ndarray

    kind = "surface"

    @cached_property
    def rotation(self) -> np.ndarray:
        """Rows u, v, w: local = R (world - vertex)."""
        return np.stack(_frame(self.axis))

    def to_local(self, points):
        return (np.asarray(points, float) - self.vertex_mm) @ self.rotation.T

    def to_world(self, points_local):
        return np.asarray(points_local, float) @ self.rotation + self.vertex_mm

    def dirs_to_local(self, dirs):
        return np.asarray(dirs, float) @ self.rotation.T

    def dirs_to_world(self, dirs_local):
        return np.asarray(dirs_local, float) @ self.rotation

    # implicit function (local) and its gradient; subclasses define them
    def implicit(self, p):  # pragma: no cover - abstract
        raise NotImplementedError

    def gradient(self, p):  # pragma: no cover - abstract
        raise NotImplementedError

    def front_sign(self) -> float:
        return -1.0

    def quadric(self):
        """(a, b, e, f, front_sign): G = a (x^2 + y^2) + b z + e z^2 + f in the local frame."""
        raise NotImplementedError  # pragma: no cover

    def refine_hits(self, origins, dirs, t0):
        """Compiled refinement: ``(t, normals (world, front side), ok)`` per ray (:func:`_refine_kernel`)."""
        a, b, e, f, sign = self.quadric()
        o = np.ascontiguousarray(origins, dtype=np.float64)
        d = np.ascontiguousarray(dirs, dtype=np.float64)
        t = np.ascontiguousarray(t0, dtype=np.float64).copy()
        nrm = np.empty_like(o)
        loc = np.empty((len(o), 2))
        done = np.empty(len(o), np.bool_)
        _kernel()(o, d, t, self.rotation, self.vertex_mm, a, b, e, f, sign, NEWTON_TOL_REL, NEWTON_MAX_ITER,
                   nrm, loc, done)
        if getattr(self, "decentred", False) or getattr(self, "aperture_half_widths_mm", ()):
            p = self.to_local(o + t[:, None] * d)  # the aperture test needs (u, v), not only rho
        elif type(self).valid is Conic.valid:
            return t, nrm, _conic_valid_rho_z(self, loc, done)
        else:
            p = np.column_stack([loc[:, 0], np.zeros(len(o)), loc[:, 1]])
        return t, nrm, done & self.valid(p)

    def refine(self, origins, dirs, t0):
        """Newton on ``G(o + t d) = 0`` from ``t0`` (the mesh hit distance), per ray.

        Parameters
        ----------
        origins, dirs : (n, 3) world, dirs unit
        t0 : (n,) starting distances

        Returns
        -------
        t : (n,) refined distances; ok : (n,) bool, converged, on the surface's own branch and
        inside its clear aperture.
        """
        o = self.to_local(origins)
        d = self.dirs_to_local(dirs)
        t = np.asarray(t0, float).copy()
        done = np.zeros(len(t), bool)
        for _ in range(NEWTON_MAX_ITER):
            act = ~done
            if not np.any(act):
                break
            p = o[act] + t[act, None] * d[act]
            g = self.implicit(p)
            dg = np.einsum("ij,ij->i", self.gradient(p), d[act])
            safe = np.where(np.abs(dg) > 1e-300, dg, 1e-300)
            step = g / safe
            t[act] -= step
            done[act] = np.abs(step) <= NEWTON_TOL_REL * (1.0 + np.abs(t[act]))
        p = o + t[:, None] * d
        ok = done & self.valid(p) & np.isfinite(t)
        return t, ok

    def normals(self, points):
        """Exact unit normals (n, 3, world) on the front side at surface points (world)."""
        g = self.gradient(self.to_local(points)) * self.front_sign()
        g /= np.linalg.norm(g, axis=1)[:, None]
        return self.dirs_to_world(g)

    def valid(self, p_local):  # pragma: no cover - abstract
        raise NotImplementedError


@dataclass(frozen=True, eq=False)
class Conic(_Surface):
    """Conic of revolution (sphere k = 0, paraboloid k = -1, hyperboloid k < -1, ellipsoid)."""

    radius_mm: float = math.inf
    conic: float = 0.0
    outer_radius_mm: float = 1.0
    inner_radius_mm: float = 0.0
    aperture_center_uv: tuple = (0.0, 0.0)  # the clear aperture's centre in the local (u, v) frame, mm
    aperture_half_widths_mm: tuple = ()     # (hx, hy): a rectangular clear aperture within the annulus
    aperture_x_uv: tuple = (1.0, 0.0)       # the rectangle's hx side, a unit vector in the local (u, v) frame

    kind = "conic"

    @property
    def decentred(self) -> bool:
        """The clear aperture is centred off the surface's axis (an off-axis segment)."""
        return bool(self.aperture_center_uv[0] or self.aperture_center_uv[1])

    def in_aperture(self, p) -> np.ndarray:
        """(n,) bool: local points whose (u, v) lie in the clear aperture: ``inner <= rho' <= outer`` about the
        aperture's centre, and inside the rectangle ``|x'| <= hx, |y'| <= hy`` when one is given."""
        x = p[:, 0] - self.aperture_center_uv[0]
        y = p[:, 1] - self.aperture_center_uv[1]
        rho = np.hypot(x, y)
        tol = 1e-9 * max(1.0, self.outer_radius_mm)
        ok = (rho <= self.outer_radius_mm + tol) & (rho >= self.inner_radius_mm - tol)
        if self.aperture_half_widths_mm:
            ex, ey = self.aperture_x_uv
            hx, hy = self.aperture_half_widths_mm
            ok &= (np.abs(x * ex + y * ey) <= hx + tol) & (np.abs(y * ex - x * ey) <= hy + tol)
        return ok

    def rho_range_mm(self) -> tuple[float, float]:
        """(smallest, largest) distance from the axis over the clear aperture's annulus."""
        off = math.hypot(*self.aperture_center_uv)
        if off == 0.0:
            return self.inner_radius_mm, self.outer_radius_mm
        return max(0.0, off - self.outer_radius_mm), off + self.outer_radius_mm

    def _max_curvature(self, rr) -> float:
        """Largest normal curvature (meridional and azimuthal) of the profile at radii ``rr``."""
        c, k = self.c, self.conic
        root = np.sqrt(np.maximum(1e-300, 1.0 - (1.0 + k) * c * c * rr * rr))
        h1 = c * rr / root
        h2 = c / root**3
        return float(np.max(np.maximum(np.abs(h2) / (1 + h1 * h1) ** 1.5, np.abs(h1) / (rr * np.sqrt(1 + h1 * h1)))))

    def _mesh_rings(self, tolerance_mm: float, samples: int):
        """(rho, phi) of a polar grid about the aperture's centre whose facets stay within ``tolerance_mm``."""
        lo, hi = self.rho_range_mm()
        rr = np.linspace(max(lo, 1e-9 * hi), hi, samples)
        curv = max(self._max_curvature(rr), 1e-12)
        r0, r1 = self.inner_radius_mm, self.outer_radius_mm
        step = math.sqrt(8.0 * tolerance_mm / curv)
        n_r = max(2, int(math.ceil((r1 - r0) / step)) + 1)
        # azimuth: the facets' chord across the ring and the aperture outline both within tolerance
        n_phi = max(24, int(math.ceil(2 * math.pi * r1 / min(step, math.sqrt(8 * tolerance_mm * r1)))))
        rho = np.linspace(r0, r1, n_r)
        # the rings are about the aperture's centre: the sag must be defined out to its offset + the outer ring
        reach = self.largest_sag_radius_mm() - math.hypot(*self.aperture_center_uv)
        rho[0], rho[-1] = covering_rim_radii_mm(r0, r1, n_phi, tolerance_mm, reach)
        return rho, np.linspace(0.0, 2 * math.pi, n_phi, endpoint=False)

    def largest_sag_radius_mm(self) -> float:
        """The largest distance from the axis at which the sag is defined (inf unless the conic closes:
        ``(1 + k) c^2 rho^2 <= 1``)."""
        ck = (1.0 + self.conic) * self.c * self.c
        return math.inf if ck <= 0.0 else 1.0 / math.sqrt(ck)

    @property
    def c(self) -> float:
        return 0.0 if math.isinf(self.radius_mm) else 1.0 / self.radius_mm

    def sag_parameters(self) -> tuple[float, float, tuple] | None:
        """(c, k, asphere coefficients (A4, A6, ...)): the sag as flat numbers, for compiled kernels
        (straylight.engine.specular_manifold_kernel); None where those kernels do not know the sag."""
        return self.c, self.conic, tuple(float(a) for a in getattr(self, "coefficients", ()))

    def slope_over_rho(self, rho2):
        """q = h'(rho) / rho = c / sqrt(1 - (1 + k) c^2 rho^2) (finite on the axis)."""
        c, k = self.c, self.conic
        return c / np.sqrt(1.0 - (1.0 + k) * c * c * rho2)

    def clear_area_mm2(self, nodes: int = 64) -> float | None:
        """Area of the surface over its clear aperture, ``int int sqrt(1 + h'(rho)^2) r dr dphi`` about the
        aperture's centre (``rho`` the distance from the axis): Gauss-Legendre in ``r``, and for a decentred
        aperture the periodic trapezoid rule in ``phi``. None for a rectangular aperture. The mesh's area
        differs (it covers the aperture: docs/optics.md, "Mesh of a lens surface")."""
        if self.aperture_half_widths_mm:
            return None
        x, w = np.polynomial.legendre.leggauss(nodes)
        a, b = self.inner_radius_mm, self.outer_radius_mm
        r, wr = 0.5 * (b - a) * x + 0.5 * (b + a), 0.5 * (b - a) * w
        if not self.decentred:
            return float(np.sum(wr * 2 * math.pi * r * np.sqrt(1.0 + r * r * self.slope_over_rho(r * r) ** 2)))
        phi = 2 * math.pi * (np.arange(4 * nodes) + 0.5) / (4 * nodes)
        cu, cv = self.aperture_center_uv
        rho2 = (cu + r[:, None] * np.cos(phi)) ** 2 + (cv + r[:, None] * np.sin(phi)) ** 2
        slope2 = rho2 * self.slope_over_rho(rho2) ** 2
        return float(np.sum((wr * r)[:, None] * np.sqrt(1.0 + slope2)) * 2 * math.pi / len(phi))

    def sag(self, rho):
        """h(rho) = c rho^2 / (1 + sqrt(1 - (1 + k) c^2 rho^2))."""
        rho = np.asarray(rho, float)
        c, k = self.c, self.conic
        return c * rho * rho / (1.0 + np.sqrt(1.0 - (1.0 + k) * c * c * rho * rho))

    def implicit(self, p):
        c, k = self.c, self.conic
        rho2 = p[:, 0] ** 2 + p[:, 1] ** 2
        return c * rho2 - 2.0 * p[:, 2] + (1.0 + k) * c * p[:, 2] ** 2

    def gradient(self, p):
        c, k = self.c, self.conic
        return np.stack([2 * c * p[:, 0], 2 * c * p[:, 1], -2.0 + 2.0 * (1.0 + k) * c * p[:, 2]], axis=1)

    def quadric(self):
        c = self.c
        return c, -2.0, (1.0 + self.conic) * c, 0.0, -1.0

    def valid(self, p):
        branch = (1.0 + self.conic) * self.c * p[:, 2] < 1.0  # the sheet through the vertex
        return branch & self.in_aperture(p)

    def mesh(self, tolerance_mm: float = 0.01):
        """(vertices (v, 3) world, faces (m, 3)), facets within about ``tolerance_mm`` of the surface,
        counter-clockwise seen from the front (+axis side)."""
        rho, phi = self._mesh_rings(tolerance_mm, 257)
        return _revolve(self, rho, phi, self.sag(rho), center=self.inner_radius_mm == 0.0)

    def to_dict(self) -> dict:
        d = {"type": "conic", "vertex_mm": self.vertex_mm.tolist(), "axis": self.axis.tolist(),
             "radius_mm": self.radius_mm, "conic": self.conic, "outer_radius_mm": self.outer_radius_mm}
        if self.inner_radius_mm:
            d["inner_radius_mm"] = self.inner_radius_mm
        d.update(self._aperture_keys())
        return d

    def _aperture_keys(self) -> dict:
        """The scene keys of an off-axis or rectangular clear aperture (world frame), empty for the default."""
        d: dict = {}
        if self.decentred:
            cu, cv = self.aperture_center_uv
            d["aperture_center_mm"] = self.to_world(np.array([[cu, cv, 0.0]]))[0].tolist()
        if self.aperture_half_widths_mm:
            d["aperture_half_widths_mm"] = [float(h) for h in self.aperture_half_widths_mm]
            ex, ey = self.aperture_x_uv
            d["aperture_x_axis"] = self.dirs_to_world(np.array([[ex, ey, 0.0]]))[0].tolist()
        return d


@dataclass(frozen=True, eq=False)
class Asphere(Conic):
    """Even asphere: the conic sag plus ``sum_i A_(2i+4) rho^(2i+4)`` (CONTRACTS §6.1 ``asphere``).

    ``coefficients = (A4, A6, ...)`` in mm^-3, mm^-5, ... as lens-design programs write them
    (CODE V ``A``, ``B``, ...; Zemax EVENASPH terms from rho^4). Implicit ``G = sag(rho) - z`` (its
    front normal ``-grad G`` is +axis at the vertex, as for the conic)."""

    coefficients: tuple = ()
    #: ((p, a_p), ...): further terms a_p rho^p of any power p >= 1 (odd aspheres, r^2), beside ``coefficients``
    power_terms: tuple = ()

    kind = "asphere"

    def _poly(self, rho2):
        """(sum A rho^n, q_poly = (d/drho sum A rho^n) / rho) for rho^2 (n = 4, 6, ..., then the power terms)."""
        s = np.zeros_like(rho2)
        q = np.zeros_like(rho2)
        for i, a in enumerate(self.coefficients):
            n = 2 * i + 4
            s = s + a * rho2 ** (n // 2)
            q = q + n * a * rho2 ** (n // 2 - 1)
        if self.power_terms:
            rho = np.sqrt(rho2)
            on_axis = rho == 0.0
            safe = np.where(on_axis, 1.0, rho)
            for p, a in self.power_terms:
                s = s + a * rho ** p
                q = q + np.where(on_axis, 2.0 * a if p == 2 else 0.0, p * a * safe ** (p - 2))
        return s, q

    @cached_property
    def dense_terms(self) -> np.ndarray:
        """The power terms by power, ``out[p] = a_p`` (empty without them: the even asphere's kernel, unchanged);
        made once per surface, not at every refinement call."""
        if not self.power_terms:
            return np.zeros(0)
        out = np.zeros(max(int(p) for p, _ in self.power_terms) + 1)
        for p, a in self.power_terms:
            out[int(p)] += a
        return out

    def sag_parameters(self) -> tuple[float, float, tuple] | None:
        """(c, k, (A4, A6, ...)) for compiled kernels that know the even asphere; None with power terms."""
        if self.power_terms:
            return None
        return Conic.sag_parameters(self)

    def sag(self, rho):
        """h(rho) + sum A_(2i+4) rho^(2i+4)."""
        rho = np.asarray(rho, float)
        return Conic.sag(self, rho) + self._poly(rho * rho)[0]

    def slope_over_rho(self, rho2):
        """q = h'(rho) / rho: c / sqrt(1 - (1 + k) c^2 rho^2) + sum n A rho^(n - 2)."""
        c, k = self.c, self.conic
        return c / np.sqrt(1.0 - (1.0 + k) * c * c * rho2) + self._poly(rho2)[1]

    def implicit(self, p):
        rho2 = p[:, 0] ** 2 + p[:, 1] ** 2
        return self.sag(np.sqrt(rho2)) - p[:, 2]

    def gradient(self, p):
        q = self.slope_over_rho(p[:, 0] ** 2 + p[:, 1] ** 2)
        return np.stack([q * p[:, 0], q * p[:, 1], -np.ones(len(p))], axis=1)

    def quadric(self):  # pragma: no cover - not a quadric
        raise TypeError("an asphere is not a quadric: use refine_hits")

    def valid(self, p):
        rho2 = p[:, 0] ** 2 + p[:, 1] ** 2
        c, k = self.c, self.conic
        inside = (1.0 + k) * c * c * rho2 <= 1.0  # the conic base has a sag there
        return inside & self.in_aperture(p)

    def refine_hits(self, origins, dirs, t0):
        """Compiled Newton on ``sag(rho) - z = 0`` along each ray from ``t0``: ``(t, normals, ok)``. The kernel
        works in the surface's local frame (:meth:`to_local`); the normals go back with :meth:`dirs_to_world`."""
        o = np.ascontiguousarray(self.to_local(origins))
        d = np.ascontiguousarray(self.dirs_to_local(dirs))
        t = np.ascontiguousarray(t0, dtype=np.float64).copy()
        nrm = np.empty_like(o)
        done = np.empty(len(o), np.bool_)
        coef = np.ascontiguousarray(self.coefficients, dtype=np.float64)
        _asphere_kernel()(o, d, t, self.c, self.conic, coef, self.dense_terms, NEWTON_TOL_REL, NEWTON_MAX_ITER, nrm,
                          done)
        return t, self.dirs_to_world(nrm), done & self.valid(o + t[:, None] * d)

    def _max_curvature(self, rr) -> float:
        """Largest normal curvature of the asphere's profile at radii ``rr`` (h'' by finite differences). An r^1
        term's cone tip has an azimuthal curvature ~ a_1 / rho without bound on the axis, over a region whose
        sag stays within a_1 rho of a plane: radii below 1e-3 of the largest are left out for it."""
        if any(p == 1 for p, _ in self.power_terms):
            rr = rr[rr >= 1e-3 * float(np.max(rr))]
        q = self.slope_over_rho(rr * rr)  # h'(rho) / rho, exact (finite on the axis)
        h1 = rr * q
        h2 = np.gradient(h1, rr)
        return float(np.max(np.maximum(np.abs(h2) / (1 + h1 * h1) ** 1.5, np.abs(q) / np.sqrt(1 + h1 * h1))))

    def mesh(self, tolerance_mm: float = 0.01):
        """Rings spaced for the largest normal curvature of the asphere's profile (sampled)."""
        rho, phi = self._mesh_rings(tolerance_mm, 1025)
        return _revolve(self, rho, phi, self.sag(rho), center=self.inner_radius_mm == 0.0)

    def to_dict(self) -> dict:
        d = Conic.to_dict(self)
        d["type"] = "asphere"
        d["coefficients"] = [float(a) for a in self.coefficients]
        if self.power_terms:
            d["power_terms"] = [[int(p), float(a)] for p, a in self.power_terms]
        return d


@dataclass(frozen=True, eq=False)
class Plane(Conic):
    """A disk or annulus through vertex_mm with normal axis (a conic with c = 0), exact in every role
    (CONTRACTS §6.4): its area is pi (outer^2 - inner^2), and the tracer counts a hit only inside its
    exact boundary (:meth:`contains`) and samples it exactly for next-event estimation.

    Its mesh only finds the hits, so it *covers* the exact region: the outer polygon is circumscribed
    about the outer circle (vertices at outer / cos(pi / n)) and the inner one inscribed in the inner
    circle; the slivers the mesh adds are refused by :meth:`contains`."""

    kind = "plane"

    def mesh(self, tolerance_mm: float = 0.01):
        r1 = self.outer_radius_mm
        n_phi = max(24, int(math.ceil(math.pi / math.acos(max(-1.0, 1.0 - tolerance_mm / r1)))))
        phi = np.linspace(0.0, 2 * math.pi, n_phi, endpoint=False)
        rho = np.array([self.inner_radius_mm, r1 / math.cos(math.pi / n_phi)])
        return _revolve(self, rho, phi, np.zeros(2), center=self.inner_radius_mm == 0.0)

    @property
    def area_mm2(self) -> float:
        """pi (outer^2 - inner^2): the exact disk or annulus."""
        return math.pi * (self.outer_radius_mm ** 2 - self.inner_radius_mm ** 2)

    def contains(self, points_mm) -> np.ndarray:
        """(n,) bool: points (world, on the plane) inside the exact disk or annulus."""
        rel = np.asarray(points_mm, dtype=np.float64) - self.vertex_mm
        along = rel @ self.axis
        rho2 = np.einsum("ij,ij->i", rel, rel) - along * along
        return (rho2 <= self.outer_radius_mm ** 2) & (rho2 >= self.inner_radius_mm ** 2)

    def to_dict(self) -> dict:
        d = {"type": "plane", "vertex_mm": self.vertex_mm.tolist(), "axis": self.axis.tolist(),
             "outer_radius_mm": self.outer_radius_mm}
        if self.inner_radius_mm:
            d["inner_radius_mm"] = self.inner_radius_mm
        return d


#: a cylinder's mesh chord sagitta at most this fraction of its radius (Cylinder.mesh): ~222 facets around
CYLINDER_SAGITTA_REL = 2e-4


@dataclass(frozen=True, eq=False)
class Cylinder(_Surface):
    """Circular cylinder about the axis line through vertex_mm, 0 <= z <= length_mm; front = outside."""

    radius_mm: float = 1.0
    length_mm: float = 1.0

    kind = "cylinder"

    def implicit(self, p):
        return p[:, 0] ** 2 + p[:, 1] ** 2 - self.radius_mm**2

    def gradient(self, p):
        return np.stack([2 * p[:, 0], 2 * p[:, 1], np.zeros(len(p))], axis=1)

    def front_sign(self) -> float:
        return 1.0

    def quadric(self):
        return 1.0, 0.0, 0.0, -self.radius_mm**2, 1.0

    def valid(self, p):
        tol = 1e-9 * max(1.0, self.length_mm)
        return (p[:, 2] >= -tol) & (p[:, 2] <= self.length_mm + tol)

    def mesh(self, tolerance_mm: float = 0.01):
        """The inscribed polygon prism, its chord sagitta at most ``tolerance_mm`` and :data:`CYLINDER_SAGITTA_REL` of
        the radius: its chords stand inside the exact wall, so a ray leaving by an open end within a sagitta of the
        wall meets a chord first (a tube's wall at the scene's 0.05 mm took 0.72 % of a disk-to-disk exchange
        through a 10 mm tube, 8 sigma; at 2e-4 of the radius, ~0.03 %)."""
        r = self.radius_mm
        tol = min(float(tolerance_mm), CYLINDER_SAGITTA_REL * r)
        n_phi = max(24, int(math.ceil(math.pi / math.acos(max(-1.0, 1.0 - tol / r)))))
        phi = np.linspace(0.0, 2 * math.pi, n_phi, endpoint=False)
        z = np.array([0.0, self.length_mm])
        ring = np.stack([r * np.cos(phi), r * np.sin(phi)], axis=1)
        verts = np.concatenate([np.column_stack([ring, np.full(n_phi, zz)]) for zz in z])
        i = np.arange(n_phi)
        j = (i + 1) % n_phi
        # outward normals: (i, j, j + n) counter-clockwise seen from outside
        faces = np.concatenate([np.stack([i, j, j + n_phi], 1), np.stack([i, j + n_phi, i + n_phi], 1)])
        return self.to_world(verts), faces

    def to_dict(self) -> dict:
        return {"type": "cylinder", "vertex_mm": self.vertex_mm.tolist(), "axis": self.axis.tolist(),
                "radius_mm": self.radius_mm, "length_mm": self.length_mm}


_KERNEL = None


def _kernel():
    """The numba kernel, compiled on first use (cache=True)."""
    global _KERNEL
    if _KERNEL is None:
        import numba

        @numba.njit(cache=True, nogil=True)
        def refine_kernel(o, d, t, rot, vertex, a, b, e, f, sign, tol, max_iter, nrm, loc, done):
            for i in range(o.shape[0]):
                ox = oy = oz = 0.0
                dx = dy = dz = 0.0
                for k in range(3):
                    ox += rot[0, k] * (o[i, k] - vertex[k])
                    oy += rot[1, k] * (o[i, k] - vertex[k])
                    oz += rot[2, k] * (o[i, k] - vertex[k])
                    dx += rot[0, k] * d[i, k]
                    dy += rot[1, k] * d[i, k]
                    dz += rot[2, k] * d[i, k]
                ti = t[i]
                ok = False
                if ti == ti and abs(ti) < 1e300:
                    for _ in range(max_iter):
                        x = ox + ti * dx
                        y = oy + ti * dy
                        z = oz + ti * dz
                        g = a * (x * x + y * y) + b * z + e * z * z + f
                        dg = 2.0 * a * (x * dx + y * dy) + (b + 2.0 * e * z) * dz
                        if dg == 0.0:
                            break
                        step = g / dg
                        ti -= step
                        if abs(step) <= tol * (1.0 + abs(ti)):
                            ok = True
                            break
                x = ox + ti * dx
                y = oy + ti * dy
                z = oz + ti * dz
                gx = sign * 2.0 * a * x
                gy = sign * 2.0 * a * y
                gz = sign * (b + 2.0 * e * z)
                norm = (gx * gx + gy * gy + gz * gz) ** 0.5
                if norm > 0.0:
                    gx /= norm
                    gy /= norm
                    gz /= norm
                for k in range(3):
                    nrm[i, k] = gx * rot[0, k] + gy * rot[1, k] + gz * rot[2, k]
                loc[i, 0] = (x * x + y * y) ** 0.5
                loc[i, 1] = z
                t[i] = ti
                done[i] = ok

        _KERNEL = refine_kernel
    return _KERNEL


def _conic_valid_rho_z(surface, loc, done):
    """``done & surface.valid(p)`` of a conic with its clear aperture about the axis, from ``loc`` = (rho, z)
    per row (the points (rho, 0, z): ``in_aperture``'s ``hypot(rho - 0, 0 - 0)`` is ``|rho|``), in one compiled
    pass (:func:`_valid_kernel`) with :meth:`Conic.valid`'s operations (the same bits)."""
    tol = 1e-9 * max(1.0, surface.outer_radius_mm)
    ok = np.empty(len(loc), np.bool_)
    _valid_kernel()(loc, done, (1.0 + surface.conic) * surface.c, surface.outer_radius_mm + tol,
                    surface.inner_radius_mm - tol, ok)
    return ok


_VALID_KERNEL = None


def _valid_kernel():
    """The numba kernel of :func:`_conic_valid_rho_z`, compiled on first use (cache=True)."""
    global _VALID_KERNEL
    if _VALID_KERNEL is None:
        import numba

        @numba.njit(cache=True, nogil=True)
        def valid_kernel(loc, done, branch_coef, rho_hi, rho_lo, ok):
            for i in range(loc.shape[0]):
                rho = abs(loc[i, 0])  # hypot(rho, 0)
                ok[i] = done[i] and branch_coef * loc[i, 1] < 1.0 and rho <= rho_hi and rho >= rho_lo

        _VALID_KERNEL = valid_kernel
    return _VALID_KERNEL


_ASPHERE_KERNEL = None


def _asphere_kernel():
    """The numba kernel of :meth:`Asphere.refine_hits`, compiled on first use (cache=True)."""
    global _ASPHERE_KERNEL
    if _ASPHERE_KERNEL is None:
        import numba

        @numba.njit(cache=True, nogil=True)
        def asphere_kernel(o, d, t, c, k, coef, a, tol, max_iter, nrm, done):
            """Local frame: origins ``o``, directions ``d``; writes local unit normals (front side) and ``done``.
            ``coef``: A4, A6...; ``a``: the power terms by power (a[p] the rho^p term; empty for an even asphere)."""
            ck = (1.0 + k) * c * c
            for i in range(o.shape[0]):
                ox, oy, oz = o[i, 0], o[i, 1], o[i, 2]
                dx, dy, dz = d[i, 0], d[i, 1], d[i, 2]
                ti = t[i]
                ok = False
                q = 0.0
                x = y = z = 0.0
                if ti == ti and abs(ti) < 1e300:
                    for _ in range(max_iter):
                        x = ox + ti * dx
                        y = oy + ti * dy
                        z = oz + ti * dz
                        r2 = x * x + y * y
                        arg = 1.0 - ck * r2
                        if arg <= 0.0:
                            break
                        root = arg ** 0.5
                        h = c * r2 / (1.0 + root)
                        q = c / root
                        p = r2
                        for m in range(coef.shape[0]):
                            n = 2 * m + 4
                            h += coef[m] * p * r2
                            q += n * coef[m] * p
                            p *= r2
                        if a.shape[0] > 0:
                            rho = r2 ** 0.5
                            if a.shape[0] > 1:  # the rho^1 term: slope a_1 / rho (0 on the axis, a cone's tip)
                                h += a[1] * rho
                                if rho > 0.0:
                                    q += a[1] / rho
                            pw = 1.0  # rho^(p - 2) as p runs from 2
                            for pp in range(2, a.shape[0]):
                                h += a[pp] * pw * r2
                                q += pp * a[pp] * pw
                                pw *= rho
                        g = h - z
                        dg = q * (x * dx + y * dy) - dz
                        if dg == 0.0:
                            break
                        step = g / dg
                        ti -= step
                        if abs(step) <= tol * (1.0 + abs(ti)):
                            ok = True
                            break
                x = ox + ti * dx
                y = oy + ti * dy
                z = oz + ti * dz
                r2 = x * x + y * y
                arg = 1.0 - ck * r2
                if arg > 0.0:
                    q = c / arg ** 0.5
                    p = r2
                    for m in range(coef.shape[0]):
                        q += (2 * m + 4) * coef[m] * p
                        p *= r2
                    if a.shape[0] > 0:
                        rho = r2 ** 0.5
                        if a.shape[0] > 1 and rho > 0.0:
                            q += a[1] / rho
                        pw = 1.0
                        for pp in range(2, a.shape[0]):
                            q += pp * a[pp] * pw
                            pw *= rho
                else:
                    ok = False
                norm = (q * q * r2 + 1.0) ** 0.5  # |(-q x, -q y, 1)|
                nrm[i, 0] = -q * x / norm
                nrm[i, 1] = -q * y / norm
                nrm[i, 2] = 1.0 / norm
                t[i] = ti
                done[i] = ok

        _ASPHERE_KERNEL = asphere_kernel
    return _ASPHERE_KERNEL


def covering_rim_radii_mm(inner_mm: float, outer_mm: float, n_phi: int, tolerance_mm: float,
                          largest_mm: float = math.inf) -> tuple[float, float]:
    """(inner, outer) ring radii of a curved surface's mesh that *cover* its clear aperture
    ``inner_mm <= rho <= outer_mm`` (docs/optics.md, "Mesh of a lens surface").

    The mesh only finds the hits: each hit is refined onto the analytic surface and counted only inside
    the clear aperture (straylight.engine.surface_geometry, straylight.intersect.exact_boundary). A ring of
    ``n_phi`` vertices on the aperture circle is an inscribed polygon whose edges cut
    ``outer (1 - cos(pi / n_phi))`` inside the circle: rays through those slivers would miss the surface.
    The outer ring is therefore circumscribed about the circle widened by ``tolerance_mm``, at
    ``(outer + tolerance) / cos(pi / n_phi)`` (its edges' midpoints at ``outer + tolerance``): the facets sit
    within about ``tolerance_mm`` of the surface along its axis, so a ray inclined by up to 45 deg to the
    axis meets the mesh within ``tolerance_mm`` sideways of where it meets the surface. The inner ring (a
    hole) is inscribed in the hole's circle narrowed likewise, at ``inner - tolerance`` (at least half the
    hole's radius; 0: none). Both
    stay where the sag is defined (below ``largest_mm``)."""
    outer = (outer_mm + tolerance_mm) / math.cos(math.pi / n_phi)
    if math.isfinite(largest_mm):
        outer = max(outer_mm, min(outer, largest_mm * (1.0 - 1e-9)))
    inner = max(0.5 * inner_mm, inner_mm - tolerance_mm)  # a hole stays a hole (0: none)
    return inner, outer


def _revolve(surface, rho, phi, z, center):
    """Rings (rho_i, z_i) x azimuths -> triangles whose normals face +w (the front of a conic). An off-axis
    aperture (``aperture_center_uv``) gets its rings about its own centre, each point at the surface's sag."""
    n_phi = len(phi)
    cphi, sphi = np.cos(phi), np.sin(phi)
    cu, cv = getattr(surface, "aperture_center_uv", (0.0, 0.0))
    rings = []
    start = 1 if center else 0
    for r, zz in zip(rho[start:], z[start:]):
        rings.append(np.column_stack([cu + r * cphi, cv + r * sphi, np.full(n_phi, zz)]))
    verts = np.concatenate(([np.array([[cu, cv, z[0]]])] if center else []) + rings)
    if cu or cv:
        verts[:, 2] = surface.sag(np.hypot(verts[:, 0], verts[:, 1]))
    faces = []
    i = np.arange(n_phi)
    j = (i + 1) % n_phi
    off = 1 if center else 0
    if center:
        faces.append(np.stack([np.zeros(n_phi, int), off + i, off + j], 1))
    for a in range(len(rings) - 1):
        A = off + a * n_phi
        B = off + (a + 1) * n_phi
        faces.append(np.stack([A + i, B + i, B + j], 1))
        faces.append(np.stack([A + i, B + j, A + j], 1))
    return surface.to_world(verts), np.concatenate(faces).astype(np.int64)


# ---------------------------------------------------------------- scene-file keys

_PLACEMENT = {"offset_mm", "tilt_deg"}
_APERTURE = {"aperture_center_mm", "aperture_half_widths_mm", "aperture_x_axis"}  # off-axis segments
_KEYS = {
    "conic": {"type", "vertex_mm", "axis", "radius_mm", "conic", "outer_radius_mm", "inner_radius_mm"} | _PLACEMENT
    | _APERTURE,
    "asphere": {"type", "vertex_mm", "axis", "radius_mm", "conic", "coefficients", "power_terms", "outer_radius_mm",
                "inner_radius_mm"} | _PLACEMENT | _APERTURE,
    "plane": {"type", "vertex_mm", "axis", "outer_radius_mm", "inner_radius_mm"} | _PLACEMENT,
    "cylinder": {"type", "vertex_mm", "axis", "radius_mm", "length_mm"} | _PLACEMENT,
}


def tilt_matrix(tilt_deg) -> np.ndarray:
    """Rz Ry Rx: rotations about the world x, then y, then z axes by ``tilt_deg = [ax, ay, az]``."""
    ax, ay, az = np.radians(np.asarray(tilt_deg, float))
    rx = np.array([[1, 0, 0], [0, math.cos(ax), -math.sin(ax)], [0, math.sin(ax), math.cos(ax)]])
    ry = np.array([[math.cos(ay), 0, math.sin(ay)], [0, 1, 0], [-math.sin(ay), 0, math.cos(ay)]])
    rz = np.array([[math.cos(az), -math.sin(az), 0], [math.sin(az), math.cos(az), 0], [0, 0, 1]])
    return rz @ ry @ rx


def _triple(d, key, where):
    v = d.get(key, [0.0, 0.0, 0.0])
    ok = isinstance(v, list) and len(v) == 3 and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                      for x in v)
    a = np.asarray(v, float) if ok else None
    if a is None or not np.all(np.isfinite(a)):
        raise GeometryError(f"{where}: surface {key!r} must be [x, y, z] (numbers), got {v!r}")
    _within_reach(float(np.abs(a).max()), f"surface {key!r}", where)
    return a


def _within_reach(value: float, what: str, where: str) -> None:
    """A position or length the tracer's float32 intersector can resolve (geometry.limits)."""
    from geometry.limits import coordinate_limit_message

    message = coordinate_limit_message(value, what)
    if message:
        raise GeometryError(f"{where}: {message}")


def _number(d, key, where, default=None, positive=False, nonneg=False):
    if key not in d:
        if default is None:
            raise GeometryError(f"{where}: surface needs {key!r}")
        return default
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or math.isnan(v):
        raise GeometryError(f"{where}: surface {key!r} must be a number, got {v!r}")
    v = float(v)
    if positive and not v > 0:
        raise GeometryError(f"{where}: surface {key!r} must be > 0, got {v!r}")
    if nonneg and not v >= 0:
        raise GeometryError(f"{where}: surface {key!r} must be >= 0, got {v!r}")
    if key != "radius_mm" or positive:  # a conic's radius of curvature may be huge (nearly flat) or inf
        _within_reach(v, f"surface {key!r}", where)
    return v


def surface_from_dict(d, where: str = "surface"):
    """A CONTRACTS §6.1 ``surface = {...}`` table -> Conic | Asphere | Plane | Cylinder; one-line errors."""
    if not isinstance(d, dict):
        raise GeometryError(f"{where}: 'surface' must be a table {{type = ..., ...}}")
    kind = d.get("type")
    if kind not in _KEYS:
        raise GeometryError(f"{where}: surface type must be one of {', '.join(_KEYS)}, got {kind!r}")
    unknown = sorted(set(d) - _KEYS[kind])
    if unknown:
        raise GeometryError(f"{where}: unknown surface key(s) {', '.join(unknown)} for {kind!r}; "
                            f"allowed: {', '.join(sorted(_KEYS[kind]))}")
    vertex = d.get("vertex_mm", [0.0, 0.0, 0.0])
    v = np.asarray(vertex, float) if isinstance(vertex, list) and len(vertex) == 3 else None
    if v is None or not np.all(np.isfinite(v)):
        raise GeometryError(f"{where}: surface 'vertex_mm' must be [x, y, z], got {vertex!r}")
    _within_reach(float(np.abs(v).max()), "surface 'vertex_mm'", where)
    axis = _unit(d.get("axis", [0.0, 0.0, 1.0]), "surface 'axis'", where)
    # placement: tilt about the vertex, then decentre (a lens file's decentre / coordinate break)
    tilt = tilt_matrix(_triple(d, "tilt_deg", where))
    axis = tilt @ axis
    axis = axis / np.linalg.norm(axis)
    v0 = v
    v = v + _triple(d, "offset_mm", where)
    if kind == "cylinder":
        return Cylinder(v, axis, _number(d, "radius_mm", where, positive=True),
                        _number(d, "length_mm", where, positive=True))
    outer = _number(d, "outer_radius_mm", where, positive=True)
    inner = _number(d, "inner_radius_mm", where, default=0.0, nonneg=True)
    if inner >= outer:
        raise GeometryError(f"{where}: surface inner_radius_mm {inner:g} must be < outer_radius_mm {outer:g}")
    if kind == "plane":
        return Plane(v, axis, math.inf, 0.0, outer, inner)
    radius = _number(d, "radius_mm", where)
    if radius == 0:
        raise GeometryError(f"{where}: surface radius_mm must be non-zero (use type = \"plane\" for a flat)")
    k = _number(d, "conic", where, default=0.0)
    c = 0.0 if math.isinf(radius) else 1.0 / radius
    if (1.0 + k) * c * c * outer * outer > 1.0:
        rmax = 1.0 / math.sqrt((1.0 + k) * c * c)
        raise GeometryError(f"{where}: the conic (radius_mm {radius:g}, conic {k:g}) has no sag beyond "
                            f"rho = {rmax:.6g} mm < outer_radius_mm {outer:g}")
    if kind == "asphere":
        coefs = d.get("coefficients", [])
        if not isinstance(coefs, list) or not all(isinstance(a, (int, float)) and not isinstance(a, bool)
                                                  and math.isfinite(a) for a in coefs):
            raise GeometryError(f"{where}: surface 'coefficients' must be a list of numbers [A4, A6, ...], "
                                f"got {coefs!r}")
        surf: Conic = Asphere(v, axis, radius, k, outer, inner, coefficients=tuple(float(a) for a in coefs),
                              power_terms=_power_terms(d.get("power_terms", []), where))
    else:
        surf = Conic(v, axis, radius, k, outer, inner)
    surf = _with_aperture(surf, d, v0, tilt, where)
    lo, hi = surf.rho_range_mm()
    if (1.0 + k) * c * c * hi * hi > 1.0:
        raise GeometryError(f"{where}: the conic (radius_mm {radius:g}, conic {k:g}) has no sag beyond "
                            f"rho = {1.0 / math.sqrt((1.0 + k) * c * c):.6g} mm, inside the off-axis aperture "
                            f"(which reaches rho = {hi:.6g} mm)")
    if kind == "asphere" and not np.all(np.isfinite(surf.sag(np.linspace(lo, hi, 513)))):
        raise GeometryError(f"{where}: the asphere's sag is not finite over its clear aperture")
    return surf


def _power_terms(terms, where: str) -> tuple:
    """The asphere's ``power_terms = [[p, a_p], ...]`` (p an integer >= 1, a_p a finite number, each p once)."""
    ok = isinstance(terms, list) and all(
        isinstance(t, list) and len(t) == 2 and isinstance(t[0], int) and not isinstance(t[0], bool) and t[0] >= 1
        and isinstance(t[1], (int, float)) and not isinstance(t[1], bool) and math.isfinite(t[1]) for t in terms)
    if not ok:
        raise GeometryError(f"{where}: surface 'power_terms' must be a list of [power, coefficient] pairs (power an "
                            f"integer >= 1, e.g. [[3, 1.2e-5], [5, -3e-8]]), got {terms!r}")
    powers = [t[0] for t in terms]
    if len(set(powers)) < len(powers):
        raise GeometryError(f"{where}: surface 'power_terms' gives a power more than once: {sorted(powers)}")
    return tuple((int(p), float(a)) for p, a in terms if a != 0.0)


def _with_aperture(surf, d, v0, tilt, where):
    """``surf`` with the off-axis / rectangular clear aperture of the scene keys (docs/reference/scene.md):
    ``aperture_center_mm`` a point (same frame as ``vertex_mm``, moved with the surface by its placement)
    through which the aperture's own axis runs parallel to ``axis``; ``aperture_half_widths_mm = [hx, hy]``
    a rectangle about that centre, its hx side along ``aperture_x_axis`` (default: world x, or y when the
    axis is along x) projected onto the plane normal to the axis."""
    import dataclasses

    changes: dict = {}
    if "aperture_center_mm" in d:
        centre = surf.vertex_mm + tilt @ (_triple(d, "aperture_center_mm", where) - v0)
        u, v, _ = surf.to_local(centre[None, :])[0]
        changes["aperture_center_uv"] = (float(u), float(v))
    if "aperture_half_widths_mm" in d:
        hw = d["aperture_half_widths_mm"]
        ok = isinstance(hw, list) and len(hw) == 2 and all(isinstance(h, (int, float)) and not isinstance(h, bool)
                                                           and math.isfinite(h) and h > 0 for h in hw)
        if not ok:
            raise GeometryError(f"{where}: surface 'aperture_half_widths_mm' must be [hx, hy] (numbers > 0), got {hw!r}")
        changes["aperture_half_widths_mm"] = (float(hw[0]), float(hw[1]))
        if "aperture_x_axis" in d:
            xdir = tilt @ _unit(d["aperture_x_axis"], "surface 'aperture_x_axis'", where)
        else:
            xdir = np.eye(3)[1] if abs(float(surf.axis[0])) > 0.9 else np.eye(3)[0]
        ex, ey, _ = surf.dirs_to_local(xdir[None, :])[0]
        if math.hypot(ex, ey) < 1e-6:
            raise GeometryError(f"{where}: surface 'aperture_x_axis' is along the axis; give a direction across it")
        changes["aperture_x_uv"] = (float(ex / math.hypot(ex, ey)), float(ey / math.hypot(ex, ey)))
    elif "aperture_x_axis" in d:
        raise GeometryError(f"{where}: surface 'aperture_x_axis' needs 'aperture_half_widths_mm' (a rectangle)")
    return dataclasses.replace(surf, **changes) if changes else surf


def analytic_part(name: str, surface, material=None, role: str = "surface", back_material=None,
                  tolerance_mm: float = 0.01, mesh=None):
    """A :class:`geometry.mesh.Part` for an analytic surface: meshed at ``tolerance_mm`` (or the given
    ``(vertices, faces)`` of a CAD mesh), with the surface kept for refinement."""
    from geometry.mesh import Part

    vertices, faces = surface.mesh(tolerance_mm) if mesh is None else mesh
    if mesh is not None and isinstance(surface, Plane):
        # a CAD mesh of a disk is a polygon inside the circle: add the project's covering mesh, so the hit
        # search finds every point of the exact disk (hits outside it are refused by the tracer)
        v2, f2 = surface.mesh(tolerance_mm)
        faces = np.concatenate([np.asarray(faces, dtype=np.int64), np.asarray(f2, dtype=np.int64) + len(vertices)])
        vertices = np.concatenate([np.asarray(vertices, dtype=np.float64), v2])
    meta: dict[str, object] = {"tolerance_mm": tolerance_mm}
    if mesh is None:
        meta["kind"] = "sheet"  # the project's mesh of a surface is an open sheet, not a leaky solid
    return Part(name, vertices, faces, material, role, meta, surface, back_material)
