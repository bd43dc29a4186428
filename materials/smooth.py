"""Smooth (delta) interface components: ``specular`` mirrors and ``dielectric`` interfaces.

CONTRACTS §5.1. These are not BRDF lobes: they send each ray into one direction (the
mirror direction, or the Snell direction), so they have no finite ``brdf``/``pdf``. A
:class:`materials.Material` keeps at most one of them apart from its scatter lobes
(``Material.smooth``), and the tracer's surface interaction asks it for the amplitude
coefficients at each hit (:meth:`Specular.coefficients`, :meth:`Dielectric.coefficients`).

Energy: the scatter lobes of the same material take their energy from the specular parts
(``Material.smooth_coefficients``): with the lobes' directional-hemispherical reflectance
rho(theta_i) for s or p light, the reflected and transmitted powers are scaled by
``g = max(0, 1 - rho / (R + T))``, so ``R' + T' + rho = max(R + T, rho) <= 1``.

References
----------
Born & Wolf, *Principles of Optics*, §1.5 (Fresnel, Snell, total internal reflection).
E. D. Palik, *Handbook of Optical Constants of Solids* (k and the absorption coefficient
``alpha = 4 pi k / lambda``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Union

import numpy as np

from materials.base import MaterialError
from materials.fresnel import fresnel_amplitudes
from materials.flags import ComponentFlags
from materials.registry import register
from materials.sampling import check_index, check_real, lazy_njit, set_fields
from materials.thin_film import layers_to_json, parse_coating, stack_amplitudes


def reflect(d, n) -> np.ndarray:
    """Mirror direction ``d - 2 (d.n) n`` (n, 3) of directions ``d`` at unit normals ``n``. One compiled
    pass, :func:`reflect_numpy`'s operations in its order (the same bits)."""
    d = np.ascontiguousarray(d, dtype=float)
    n = np.ascontiguousarray(n, dtype=float)
    if d.ndim != 2 or d.shape != n.shape or d.shape[1] != 3:
        return reflect_numpy(d, n)
    out = np.empty_like(d)
    if len(d):
        lazy_njit(_reflect_loop, "numpy")(d, n, out)
    return out


def _reflect_loop(d, n, out):
    """:func:`reflect_numpy` row by row (einsum's dot order ``(d0 n0 + d2 n2) + d1 n1``)."""
    for r in range(len(d)):
        two_dot = 2.0 * ((d[r, 0] * n[r, 0] + d[r, 2] * n[r, 2]) + d[r, 1] * n[r, 1])
        for j in range(3):
            out[r, j] = d[r, j] - two_dot * n[r, j]


def reflect_numpy(d, n) -> np.ndarray:
    """:func:`reflect` in vectorised numpy (the reference it is tested against)."""
    d = np.asarray(d, float)
    n = np.asarray(n, float)
    return d - 2.0 * np.einsum("ij,ij->i", d, n)[:, None] * n


def refract(d, n, eta, cos_t) -> np.ndarray:
    """Snell direction ``eta d + (eta cos_i - cos_t) n`` (n, 3), normalised.

    ``n`` is the unit normal on the incident side (``d . n < 0``), ``eta = n1 / n2`` (real),
    ``cos_t`` the cosine of the refraction angle (>= 0); Born & Wolf §1.5.1 in vector form. One
    compiled pass, :func:`refract_numpy`'s operations in its order (the same bits).
    """
    d = np.ascontiguousarray(d, dtype=float)
    n = np.ascontiguousarray(n, dtype=float)
    if d.ndim != 2 or d.shape != n.shape or d.shape[1] != 3:
        return refract_numpy(d, n, eta, cos_t)
    m = len(d)
    eta_rows = np.ascontiguousarray(np.broadcast_to(np.asarray(eta, float), (m,)))
    cos_t_rows = np.ascontiguousarray(np.broadcast_to(np.asarray(cos_t, float), (m,)))
    out = np.empty_like(d)
    if m:
        lazy_njit(_refract_loop, "numpy")(d, n, eta_rows, cos_t_rows, out)
    return out


def _refract_loop(d, n, eta, cos_t, out):
    """:func:`refract_numpy` row by row (einsum's dot order; ``np.linalg.norm``'s ``(t0^2 + t1^2) + t2^2``)."""
    for r in range(len(d)):
        cos_i = -((d[r, 0] * n[r, 0] + d[r, 2] * n[r, 2]) + d[r, 1] * n[r, 1])
        e = eta[r]
        k = e * cos_i - cos_t[r]
        t0 = e * d[r, 0] + k * n[r, 0]
        t1 = e * d[r, 1] + k * n[r, 1]
        t2 = e * d[r, 2] + k * n[r, 2]
        norm = np.sqrt((t0 * t0 + t1 * t1) + t2 * t2)
        out[r, 0], out[r, 1], out[r, 2] = t0 / norm, t1 / norm, t2 / norm


def refract_numpy(d, n, eta, cos_t) -> np.ndarray:
    """:func:`refract` in vectorised numpy (the reference it is tested against)."""
    d = np.asarray(d, float)
    n = np.asarray(n, float)
    cos_i = -np.einsum("ij,ij->i", d, n)
    eta = np.broadcast_to(np.asarray(eta, float), cos_i.shape)
    t = eta[:, None] * d + (eta * cos_i - np.asarray(cos_t, float))[:, None] * n
    return t / np.linalg.norm(t, axis=1)[:, None]


@dataclass(frozen=True)
class Coefficients:
    """Amplitude coefficients of one smooth interaction per ray, in the s/p basis
    (:mod:`materials.mueller`).

    r_s, r_p : (n,) complex, reflection; ``|r|^2`` is the reflected power fraction
    t_s, t_p : (n,) complex, transmission scaled so that ``|t|^2`` is the transmitted power
        fraction (zeros for a mirror and under total internal reflection)
    cos_t : (n,) cosine of the refraction angle (0 where nothing is transmitted)
    eta : (n,) n_incident / n_transmitted (real parts), for :func:`refract`
    """

    r_s: np.ndarray
    r_p: np.ndarray
    t_s: np.ndarray
    t_p: np.ndarray
    cos_t: np.ndarray
    eta: np.ndarray

    @property
    def R_s(self):
        return np.abs(self.r_s) ** 2

    @property
    def R_p(self):
        return np.abs(self.r_p) ** 2

    @property
    def T_s(self):
        return np.abs(self.t_s) ** 2

    @property
    def T_p(self):
        return np.abs(self.t_p) ** 2

    def reflectance(self, polarization: str = "u"):
        return {"s": self.R_s, "p": self.R_p, "u": 0.5 * (self.R_s + self.R_p)}[polarization]

    def transmittance(self, polarization: str = "u"):
        return {"s": self.T_s, "p": self.T_p, "u": 0.5 * (self.T_s + self.T_p)}[polarization]

    def scaled(self, g_s, g_p) -> "Coefficients":
        """Powers scaled by g_s, g_p (amplitudes by their square roots)."""
        a = np.sqrt(np.asarray(g_s, float))
        b = np.sqrt(np.asarray(g_p, float))
        return Coefficients(self.r_s * a, self.r_p * b, self.t_s * a, self.t_p * b, self.cos_t, self.eta)


@register("specular")
@dataclass(frozen=True)
class Specular:
    """Mirror reflection, a delta lobe (CONTRACTS §5.1 ``specular``).

    Parameters
    ----------
    r : float, optional
        Constant reflectance in [0, 1] for every polarization (amplitudes ``r_s = -sqrt(r)``,
        ``r_p = +sqrt(r)``: an ideal mirror, no retardance between s and p).
    n : float or [n, k], optional
        Substrate index: Fresnel ``r_s``, ``r_p`` (:func:`materials.fresnel.fresnel_amplitudes`)
        for the ray's polarization. Exactly one of ``r`` and ``n``.
    weight : float
        Multiplies the reflected power, in [0, 1] (default 1).
    coating : str or list, optional
        A thin-film stack on the mirror (:mod:`materials.thin_film`): a named design or layers
        ``[{"n": ..., "thickness_nm": ...}, ...]``, outermost first; needs ``n`` and the wavelength.
    wavelength_nm : float, optional
        The traced wavelength for a coating (the material's, by default).
    """

    r: Optional[float] = None
    n: Optional[Union[float, tuple]] = None
    weight: float = 1.0
    coating: Optional[object] = None
    wavelength_nm: Optional[float] = None

    flags = ComponentFlags.DELTA_REFLECTION | ComponentFlags.POLARIZING
    reciprocal = True

    def __post_init__(self):
        o = "specular"
        set_fields(self, weight=check_real(o, "weight", self.weight, lo=0.0, hi=1.0))
        if (self.n is None) == (self.r is None):
            raise MaterialError(f"{o}: give exactly one of 'n' (refractive index) or 'r' (constant reflectance)")
        if self.r is not None:
            set_fields(self, r=check_real(o, "r", self.r, lo=0.0, hi=1.0))
        else:
            n, k = check_index(o, "n", self.n)
            set_fields(self, n=(n, k) if k else n)
        _check_coating(self, o)
        if self.coating is not None and self.r is not None:
            raise MaterialError(f"{o}: a 'coating' needs the substrate index 'n', not a constant 'r'")

    @property
    def wavelength_optional(self) -> bool:
        """Only a coating needs the wavelength."""
        return self.coating is None

    @classmethod
    def example(cls) -> "Specular":
        return cls(n=(0.96, 6.69))

    @property
    def index(self) -> complex:
        return complex(*self.n) if isinstance(self.n, tuple) else complex(self.n, 0.0)

    def coefficients(self, cos_i, back: bool = False) -> Coefficients:
        """Reflection amplitudes at incidence cosines ``cos_i`` (n,); a mirror reflects the same
        on both sides."""
        c = np.atleast_1d(np.asarray(cos_i, float))
        zero = np.zeros(c.shape, complex)
        if self.r is not None:
            a = np.sqrt(self.r * self.weight)
            rs = np.full(c.shape, -a, complex)
            rp = np.full(c.shape, a, complex)
        else:
            if self.coating is not None:
                rs, rp, _, _, _, _ = stack_amplitudes(c, 1.0, self.index, _layers(self), self.wavelength_nm)
            else:
                rs, rp, _, _, _ = fresnel_amplitudes(c, self.index)
            if self.weight != 1.0:
                w = np.sqrt(self.weight)
                rs, rp = rs * w, rp * w
        return Coefficients(rs, rp, zero, zero, np.zeros(c.shape), np.ones(c.shape))

    def to_dict(self) -> dict:
        d = {"type": "specular"}
        if self.r is not None:
            d["r"] = self.r
        else:
            d["n"] = list(self.n) if isinstance(self.n, tuple) else self.n
        if self.weight != 1.0:
            d["weight"] = self.weight
        _coating_to_dict(self, d)
        return d


@register("dielectric")
@dataclass(frozen=True)
class Dielectric:
    """Smooth interface to a transparent medium (CONTRACTS §5.1 ``dielectric``).

    The medium of index ``n`` lies on the part's back side (inside a closed mesh; the back
    of an analytic surface), ``n_outside`` on the front. Fresnel s and p reflection and
    transmission, Snell refraction, total internal reflection.

    Parameters
    ----------
    n : float or [n, k]
        Index of the medium. ``k`` enters the reflectance seen from outside and the bulk
        absorption ``4 pi k / lambda``; light leaving the medium sees the real index ``n``
        (valid for k << n).
    n_outside : float
        Index on the front side (default 1).
    absorption_per_mm : float
        Bulk absorption coefficient inside the medium, 1/mm (default 0): a path of length
        L keeps ``exp(-alpha L)`` of its power, with ``alpha = absorption_per_mm + 4 pi k / lambda``.
    wavelength_nm : float, optional
        Needed only with ``k > 0`` or a coating (the material's, by default).
    coating : str or list, optional
        A thin-film stack on the outer (front) side (:mod:`materials.thin_film`): a named design or
        layers ``[{"n": ..., "thickness_nm": ...}, ...]``, outermost first. Light from inside the
        medium meets the same stack in reverse order.
    """

    n: Union[float, tuple]
    n_outside: float = 1.0
    absorption_per_mm: float = 0.0
    wavelength_nm: Optional[float] = None
    coating: Optional[object] = None

    flags = ComponentFlags.DELTA_REFLECTION | ComponentFlags.DELTA_TRANSMISSION | ComponentFlags.POLARIZING
    reciprocal = True

    def __post_init__(self):
        o = "dielectric"
        n, k = check_index(o, "n", self.n)
        set_fields(
            self,
            n=(n, k) if k else n,
            n_outside=check_real(o, "n_outside", self.n_outside, lo=0.0, lo_open=True),
            absorption_per_mm=check_real(o, "absorption_per_mm", self.absorption_per_mm, lo=0.0),
        )
        if self.wavelength_nm is not None:
            set_fields(self, wavelength_nm=check_real(o, "wavelength_nm", self.wavelength_nm, lo=0.0, lo_open=True))
        _check_coating(self, o)

    @classmethod
    def example(cls) -> "Dielectric":
        return cls(n=1.5195)

    @property
    def wavelength_optional(self) -> bool:
        """Only an absorbing index (k > 0) or a coating needs the wavelength."""
        return self.k == 0.0 and self.coating is None

    @property
    def n_real(self) -> float:
        return self.n[0] if isinstance(self.n, tuple) else float(self.n)

    @property
    def k(self) -> float:
        return self.n[1] if isinstance(self.n, tuple) else 0.0

    @property
    def attenuation_per_mm(self) -> float:
        """alpha = absorption_per_mm + 4 pi k / lambda (1/mm) inside the medium."""
        if self.k == 0.0:
            return self.absorption_per_mm
        if self.wavelength_nm is None:
            raise MaterialError("dielectric: an index [n, k] with k > 0 needs wavelength_nm")
        return self.absorption_per_mm + 4.0 * np.pi * self.k / (self.wavelength_nm * 1e-6)

    def coefficients(self, cos_i, back: bool = False) -> Coefficients:
        """Fresnel amplitudes at incidence cosines ``cos_i`` (n,), from the front (outside ->
        medium) or, with ``back=True``, from inside the medium. A real index without a coating: one
        compiled pass (:func:`_real_index_loop`), :meth:`coefficients_numpy`'s operations in its order
        (the same bits)."""
        c = np.atleast_1d(np.asarray(cos_i, float))
        if self.k != 0.0 or self.coating is not None or c.ndim != 1:
            return self.coefficients_numpy(c, back)
        m = np.asarray(self.n_outside / self.n_real if back else complex(self.n_real, self.k) / self.n_outside, complex)
        m_real = float(np.real(m))
        out = np.empty((4, len(c)), complex)
        cos_t = np.empty(len(c))
        if len(c):
            lazy_njit(_real_index_loop, "numpy")(np.ascontiguousarray(c), complex(m * m), complex(2.0 * m), m_real,
                                                 out, cos_t)
        return Coefficients(out[0], out[1], out[2], out[3], cos_t, np.full(c.shape, 1.0 / m_real))

    def coefficients_numpy(self, cos_i, back: bool = False) -> Coefficients:
        """:meth:`coefficients` in vectorised numpy (the reference the compiled pass is tested against;
        every index and coating)."""
        c = np.atleast_1d(np.asarray(cos_i, float))
        if back:
            m = self.n_outside / self.n_real
        else:
            m = complex(self.n_real, self.k) / self.n_outside
        rs, rp, ts, tp, q = fresnel_amplitudes(c, m)
        with np.errstate(divide="ignore", invalid="ignore"):
            if np.imag(m) == 0:
                f = np.where(c > 0, q.real / np.where(c > 0, c, 1.0), 0.0)
            else:  # absorbing medium entered: the power that enters is 1 - R
                Rs = np.abs(rs) ** 2
                Rp = np.abs(rp) ** 2
                f_s = np.where(np.abs(ts) > 0, (1.0 - Rs) / np.abs(ts) ** 2, 0.0)
                f_p = np.where(np.abs(tp) > 0, (1.0 - Rp) / np.abs(tp) ** 2, 0.0)
        if np.imag(m) == 0:
            ts = ts * np.sqrt(f)
            tp = tp * np.sqrt(f)
        else:
            ts = ts * np.sqrt(f_s)
            tp = tp * np.sqrt(f_p)
        m_real = float(np.real(m))
        sin2_t = (1.0 - c * c) / (m_real * m_real)
        tir = sin2_t >= 1.0
        cos_t = np.where(tir, 0.0, np.sqrt(np.maximum(0.0, 1.0 - sin2_t)))
        if self.coating is not None:  # the stack replaces the bare amplitudes; directions (Snell) are unchanged
            layers = _layers(self)
            if back:
                rs, rp, _, _, ts, tp = stack_amplitudes(c, self.n_real, complex(self.n_outside), layers[::-1],
                                                        self.wavelength_nm)
            else:
                rs, rp, _, _, ts, tp = stack_amplitudes(c, self.n_outside, complex(self.n_real, self.k), layers,
                                                        self.wavelength_nm)
        ts = np.where(tir, 0.0, ts)
        tp = np.where(tir, 0.0, tp)
        return Coefficients(rs, rp, ts, tp, cos_t, np.full(c.shape, 1.0 / m_real))

    def to_dict(self) -> dict:
        d = {"type": "dielectric", "n": list(self.n) if isinstance(self.n, tuple) else self.n}
        if self.n_outside != 1.0:
            d["n_outside"] = self.n_outside
        if self.absorption_per_mm:
            d["absorption_per_mm"] = self.absorption_per_mm
        if self.wavelength_nm is not None:
            d["wavelength_nm"] = self.wavelength_nm
        _coating_to_dict(self, d)
        return d


def _real_index_loop(c, m2, two_m, m_real, out, cos_t):
    """:meth:`Dielectric.coefficients_numpy` row by row for a real index and no coating:
    :func:`materials.fresnel.fresnel_amplitudes`' rows (its compiled loop's operations), the
    transmission scaled by ``sqrt(Re q / cos_i)`` as numpy multiplies complex by real (``(x + 0j) z``),
    Snell's ``cos_t``, zero transmission under total internal reflection."""

    def cdiv(a, b):  # as in materials/fresnel.py's loop: numba's cache does not see a change in a jitted callee
        ar, ai, br, bi = a.real, a.imag, b.real, b.imag
        if abs(br) >= abs(bi):
            if br == 0.0 and bi == 0.0:
                return complex(ar / abs(br), ai / abs(br))
            rat = bi / br
            scl = 1.0 / (br + bi * rat)
            return complex((ar + ai * rat) * scl, (ai - ar * rat) * scl)
        rat = br / bi
        scl = 1.0 / (bi + br * rat)
        return complex((ar * rat + ai) * scl, (ai * rat - ar) * scl)

    mr2 = m_real * m_real
    for r in range(len(c)):
        x = c[r]
        cz = complex(x, 0.0)
        q = np.sqrt((m2 - (1.0 - x * x)) + 0j)
        ds = cz + q
        m2c = m2 * cz
        dp = m2c + q
        out[0, r] = cdiv(cz - q, ds)
        out[1, r] = cdiv(m2c - q, dp)
        ts = cdiv(complex(2.0 * x, 0.0), ds)
        tp = cdiv(two_m * cz, dp)
        f = q.real / x if x > 0 else 0.0
        sf = np.sqrt(f)
        ts = complex(ts.real * sf - ts.imag * 0.0, ts.real * 0.0 + ts.imag * sf)
        tp = complex(tp.real * sf - tp.imag * 0.0, tp.real * 0.0 + tp.imag * sf)
        sin2_t = (1.0 - x * x) / mr2
        if sin2_t >= 1.0:
            cos_t[r] = 0.0
            out[2, r] = 0j
            out[3, r] = 0j
        else:
            w = 1.0 - sin2_t
            cos_t[r] = np.sqrt(0.0 if w <= 0.0 else w)
            out[2, r] = ts
            out[3, r] = tp


def _check_coating(component, owner: str) -> None:
    """Parse ``coating`` (a design name stays a name until the wavelength is known, then becomes
    its layers at that wavelength, so a later change of traced wavelength keeps the thicknesses)."""
    if component.coating is None:
        return
    layers = parse_coating(owner, component.coating, component.wavelength_nm)
    if layers is not None:
        set_fields(component, coating=layers)


def _layers(component) -> tuple:
    if component.wavelength_nm is None or isinstance(component.coating, str):
        raise MaterialError(f"{type(component).__name__.lower()}: a coating needs the wavelength (wavelength_nm)")
    return component.coating


def _coating_to_dict(component, d: dict) -> None:
    if component.coating is not None:
        d["coating"] = component.coating if isinstance(component.coating, str) else layers_to_json(component.coating)
        if component.wavelength_nm is not None:
            d.setdefault("wavelength_nm", component.wavelength_nm)
