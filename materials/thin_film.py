"""Thin-film coatings: reflection and transmission of a layer stack by characteristic matrices.

CONTRACTS §5.1 ``coating`` on ``specular`` and ``dielectric`` components. A stack is a sequence of
homogeneous layers (complex index N = n + ik, physical thickness d), outermost layer first, between
an incidence medium (index n_in, real) and a substrate (index N_sub). With the invariant
alpha = n_in sin(theta_in), each medium has N cos(theta) = sqrt(N^2 - alpha^2) (the root with
Im >= 0: decaying fields) and a tilted optical admittance (Macleod, *Thin-Film Optical Filters*,
4th ed., §2.6)::

    s:  eta = N cos(theta)              p:  eta = N^2 / (N cos(theta)) = N / cos(theta)

Layer j has the phase thickness delta_j = 2 pi N_j d_j cos(theta_j) / lambda and the characteristic
matrix M_j = [[cos delta_j, -i sin delta_j / eta_j], [-i eta_j sin delta_j, cos delta_j]] (Macleod's
matrix with i -> -i: he writes N = n - ik, this project n + ik, i.e. fields exp(-i omega t)); the
stack's [B, C]^T = M_1 M_2 ... M_q [1, eta_sub]^T, Y = C / B (Macleod eq. 2.98-2.106), and::

    r_s = (eta_in - Y) / (eta_in + Y)       r_p = (Y - eta_in) / (Y + eta_in)
    T   = 4 Re(eta_in) Re(eta_sub) / |eta_in B + C|^2      A = 1 - R - T

The p sign follows :func:`materials.fresnel.fresnel_amplitudes` (r_p = -r_s at normal incidence):
with no layers these are exactly its bare-interface amplitudes and powers. The transmitted
amplitude returned has modulus sqrt(T) and the phase of t = 2 eta_in / (eta_in B + C), so that
``|t|^2`` is the transmitted power fraction as the tracer's Mueller calculus expects.

Named designs (layers from the outside in; lambda0 = the material's ``wavelength_nm``):

- ``mgf2_quarter_wave``: MgF2 (n = 1.38), d = lambda0 / (4 x 1.38). On n = 1.5168 at lambda0 it
  reflects ((1.5168 - 1.38^2) / (1.5168 + 1.38^2))^2 = 1.26 % at normal incidence... computed exactly
  by :func:`quarter_wave_reflectance` (1.28 % with the rounded indices of the contract).
- ``broadband_ar``: the quarter-half-quarter design (Lockhart & King 1947; Macleod §4.3): MgF2
  (1.38) lambda0/4, ZrO2 (2.05) lambda0/2, Al2O3 (1.62) lambda0/4: below 0.5 % over most of the
  visible on crown glass.
- ``protected_aluminium``: one SiO2 (n = 1.46) half-wave overcoat at lambda0 (an absentee layer at
  lambda0, so the mirror keeps aluminium's reflectance there); the substrate is the ``specular``
  component's own ``n`` (aluminium's n, k).
"""
from __future__ import annotations

from typing import Optional, Sequence

import numpy as np

from materials.base import MaterialError

#: name -> [(n, k, optical thickness in units of lambda0 / n, i.e. d = fraction x lambda0 / n)]
NAMED_DESIGNS = {
    "mgf2_quarter_wave": [(1.38, 0.0, 0.25)],
    "broadband_ar": [(1.38, 0.0, 0.25), (2.05, 0.0, 0.5), (1.62, 0.0, 0.25)],
    "protected_aluminium": [(1.46, 0.0, 0.5)],
}

Layer = tuple  # (n, k, thickness_nm)


def parse_coating(owner: str, value, wavelength_nm) -> Optional[tuple]:
    """A material file's ``coating`` (a design name or a list of ``{"n", "thickness_nm"}``) ->
    a tuple of (n, k, thickness_nm) layers, outermost first. A named design needs the wavelength
    (its thicknesses are fractions of it); it returns None while that is unknown."""
    if isinstance(value, str):
        if value not in NAMED_DESIGNS:
            raise MaterialError(f"{owner}: unknown coating {value!r}; named designs: {', '.join(sorted(NAMED_DESIGNS))}, "
                                "or a list of layers [{\"n\": 1.38, \"thickness_nm\": 99.6}, ...]")
        if wavelength_nm is None:
            return None
        return tuple((n, k, frac * float(wavelength_nm) / n) for n, k, frac in NAMED_DESIGNS[value])
    if not isinstance(value, (list, tuple)) or not value:
        raise MaterialError(f"{owner}: 'coating' must be a design name or a non-empty list of layers, got {value!r}")
    layers = []
    for i, layer in enumerate(value):
        if isinstance(layer, (list, tuple)) and len(layer) == 3:  # already parsed (n, k, d)
            n, k, d = (float(x) for x in layer)
        elif isinstance(layer, dict):
            extra = set(layer) - {"n", "thickness_nm"}
            if extra or "n" not in layer or "thickness_nm" not in layer:
                raise MaterialError(f"{owner}: coating layer {i + 1} must have exactly 'n' and 'thickness_nm', got {sorted(layer)}")
            nk = layer["n"]
            if isinstance(nk, (list, tuple)):
                if len(nk) != 2:
                    raise MaterialError(f"{owner}: coating layer {i + 1}: 'n' must be a number or [n, k], got {nk!r}")
                n, k = float(nk[0]), float(nk[1])
            else:
                n, k = float(nk), 0.0
            d = float(layer["thickness_nm"])
        else:
            raise MaterialError(f"{owner}: coating layer {i + 1} must be {{\"n\": ..., \"thickness_nm\": ...}}, got {layer!r}")
        if not (np.isfinite(n) and n > 0 and np.isfinite(k) and k >= 0 and np.isfinite(d) and d >= 0):
            raise MaterialError(f"{owner}: coating layer {i + 1}: need n > 0, k >= 0, thickness_nm >= 0; got n={n}, k={k}, "
                                f"thickness_nm={d}")
        layers.append((n, k, d))
    return tuple(layers)


def layers_to_json(layers: Sequence[Layer]) -> list:
    return [{"n": [n, k] if k else n, "thickness_nm": d} for n, k, d in layers]


def _n_cos(N, alpha2):
    """N cos(theta) = sqrt(N^2 - alpha^2) on the branch with Im >= 0 (and Re >= 0 when Im = 0)."""
    q = np.sqrt(N * N - alpha2 + 0j)
    flip = (q.imag < 0) | ((q.imag == 0) & (q.real < 0))
    return np.where(flip, -q, q)


def stack_amplitudes(cos_in, n_in: float, n_sub: complex, layers: Sequence[Layer], wavelength_nm: float):
    """Reflection amplitudes and transmitted powers of a coated interface (module docstring).

    Parameters
    ----------
    cos_in : (n,) cosine of the incidence angle in the incidence medium (>= 0)
    n_in : real index of the incidence medium
    n_sub : index of the medium beyond the stack (complex for a metal or an absorbing glass)
    layers : (n, k, thickness_nm) from the incidence side inward
    wavelength_nm : vacuum wavelength of the traced light

    Returns
    -------
    r_s, r_p : (n,) complex amplitudes; T_s, T_p : (n,) transmitted power fractions;
    t_s, t_p : (n,) complex, ``|t|^2 = T`` with the stack's transmission phase
    """
    c = np.clip(np.atleast_1d(np.asarray(cos_in, float)), 0.0, 1.0)
    alpha2 = (n_in * n_in) * (1.0 - c * c)
    q_in = np.maximum(n_in * c, 1e-300) + 0j
    q_sub = _n_cos(complex(n_sub), alpha2)
    out = {}
    for pol in ("s", "p"):
        if pol == "s":
            eta_in, eta_sub = q_in, q_sub
        else:
            eta_in = n_in * n_in / q_in
            with np.errstate(divide="ignore", invalid="ignore"):
                eta_sub = np.where(np.abs(q_sub) > 0, complex(n_sub) ** 2 / np.where(np.abs(q_sub) > 0, q_sub, 1.0), 1e300)
        B = np.ones(c.shape, complex)
        C = eta_sub.astype(complex)
        for n, k, d in reversed(tuple(layers)):
            N = complex(n, k)
            q = _n_cos(N, alpha2)
            eta = q if pol == "s" else N * N / np.where(np.abs(q) > 0, q, 1e-300)
            delta = 2.0 * np.pi * q * d / wavelength_nm
            cd, sd = np.cos(delta), np.sin(delta)
            B, C = cd * B - 1j * sd / eta * C, -1j * eta * sd * B + cd * C
        denom = eta_in * B + C
        Y = C / B
        r = (eta_in - Y) / (eta_in + Y) if pol == "s" else (Y - eta_in) / (Y + eta_in)
        T = 4.0 * eta_in.real * np.real(eta_sub) / np.abs(denom) ** 2
        T = np.clip(np.where(np.isfinite(T), T, 0.0), 0.0, 1.0)
        t_dir = 2.0 * eta_in / denom
        with np.errstate(divide="ignore", invalid="ignore"):
            phase = np.where(np.abs(t_dir) > 0, t_dir / np.abs(t_dir), 1.0)
        out[pol] = (r, T, np.sqrt(T) * phase)
    (rs, Ts, ts), (rp, Tp, tp) = out["s"], out["p"]
    return rs, rp, Ts, Tp, ts, tp


def quarter_wave_reflectance(n_in: float, n_layer: float, n_sub: float) -> float:
    """Normal-incidence reflectance of one quarter-wave layer at its design wavelength,
    ((n_in n_sub - n_layer^2) / (n_in n_sub + n_layer^2))^2 (Macleod §3.2): the closed form the
    matrix calculation must reproduce."""
    y = n_layer * n_layer / n_sub
    return ((n_in - y) / (n_in + y)) ** 2
