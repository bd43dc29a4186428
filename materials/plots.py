"""Figures for measured scans, fits and materials (matplotlib, Agg, PNG).

- :func:`plot_fit`: like the seed paper's Figs. 5-6: one row per incidence angle,
  one column per polarization (s and p side by side); measured BRDF with error bars,
  the fitted total and each component drawn separately; log BRDF against the signed
  in-plane viewing angle (negative = backscatter half-plane).
- :func:`plot_material`: in-plane BRDF at several incidence angles and rho(theta_i).

Uses ``matplotlib.figure.Figure`` with the Agg canvas directly: no pyplot global state.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

import atomicio
from materials.albedo import directional_hemispherical_reflectance
from materials.base import directions_from_angles

_POL_NAMES = {"s": "s-polarized", "p": "p-polarized", "u": "unpolarized"}


def _in_plane(component, theta_i_deg, signed_theta_r_deg, polarization):
    tr = np.asarray(signed_theta_r_deg, float)
    wi, wo = directions_from_angles(np.radians(theta_i_deg), np.radians(np.abs(tr)), np.where(tr < 0, np.pi, 0.0))
    return component.brdf(wi, wo, polarization)


def _save(fig, path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(fig)
    return atomicio.write_figure(fig, path, dpi=110)


def plot_fit(scan, result, path, title: str | None = None) -> Path:
    """Measured points and the fitted model per incidence angle and polarization (PNG).

    Parameters
    ----------
    scan : materials.scan.Scan
    result : materials.fit.FitResult
    path : path of the PNG to write
    """
    angles = scan.incidence_angles_deg
    pols = scan.polarizations
    fig = Figure(figsize=(4.6 * len(pols), 2.9 * len(angles)), layout="constrained")
    axes = fig.subplots(len(angles), len(pols), squeeze=False, sharex=True)
    grid = np.linspace(-89.5, 89.5, 1433)
    comps = list(result.components)
    for i, t in enumerate(angles):
        for j, pol in enumerate(pols):
            ax = axes[i, j]
            sel = scan.select((scan.theta_i_deg == t) & (scan.polarization == pol))
            if len(sel) == 0:
                ax.set_visible(False)
                continue
            good = ~sel.flagged
            x = sel.signed_theta_r_deg[good]
            y = sel.brdf_per_sr[good]
            err = np.nan_to_num(sel.brdf_std_per_sr[good])
            lower = np.minimum(err, 0.999 * y)  # keep the bar above zero on a log axis
            ax.errorbar(x, y, yerr=[lower, err], fmt="o", ms=2.5, lw=0.8, color="k", label="measured")
            total = np.zeros_like(grid)
            for k, c in enumerate(comps):
                f = _in_plane(c, t, grid, pol)
                total += f
                if len(comps) > 1:
                    ax.plot(grid, np.where(f > 0, f, np.nan), lw=0.9, ls="--",
                            label=getattr(c, "type_name", type(c).__name__))
            ax.plot(grid, np.where(total > 0, total, np.nan), lw=1.4, color="C3", label="fit (total)")
            ax.set_yscale("log")
            rms = result.rms_log10.get((float(t), pol))
            note = f", rms {rms:.3f} dex" if rms is not None else ""
            nflag = int(sel.flagged.sum())
            note += f", {nflag} flagged" if nflag else ""
            ax.set_title(f"theta_i = {t:g} deg, {_POL_NAMES[pol]}{note}", fontsize=9)
            ax.axvline(t, color="0.7", lw=0.6)
            ax.grid(True, which="both", alpha=0.25)
            if j == 0:
                ax.set_ylabel("BRDF (1/sr)")
            if i == len(angles) - 1:
                ax.set_xlabel("viewing angle theta_r (deg; < 0: backscatter side)")
            if i == 0 and j == 0:
                ax.legend(fontsize=7, loc="lower left")
    fig.suptitle(title or f"{result.model} fit at {result.wavelength_nm:g} nm", fontsize=11)
    return _save(fig, path)


def plot_material(material, path, theta_i_deg=(10.0, 30.0, 50.0, 70.0, 80.0), polarizations=("s", "p"),
                  title: str | None = None) -> Path:
    """In-plane BRDF at several incidence angles (one panel per polarization) and rho(theta_i) (PNG)."""
    fig = Figure(figsize=(4.6 * (len(polarizations) + 1), 3.6), layout="constrained")
    axes = fig.subplots(1, len(polarizations) + 1, squeeze=False)[0]
    grid = np.linspace(-89.5, 89.5, 1433)
    for j, pol in enumerate(polarizations):
        ax = axes[j]
        for k, t in enumerate(theta_i_deg):
            f = _in_plane(material, t, grid, pol)
            ax.plot(grid, np.where(f > 0, f, np.nan), lw=1.1, color=f"C{k}", label=f"theta_i = {t:g} deg")
            ax.axvline(t, color=f"C{k}", lw=0.5, alpha=0.4)
        ax.set_yscale("log")
        ax.set_xlabel("viewing angle theta_r (deg; < 0: backscatter side)")
        ax.set_ylabel("BRDF (1/sr)")
        ax.set_title(f"in-plane BRDF, {_POL_NAMES[pol]}", fontsize=9)
        ax.grid(True, which="both", alpha=0.25)
        ax.legend(fontsize=7)
    ax = axes[-1]
    th = np.linspace(0.0, 89.0, 90)
    for pol in polarizations:
        rho = directional_hemispherical_reflectance(material, np.radians(th), pol)
        ax.plot(th, rho, label=_POL_NAMES[pol])
    ax.set_yscale("log")
    ax.set_xlabel("incidence angle theta_i (deg)")
    ax.set_ylabel("directional-hemispherical reflectance rho")
    ax.set_title("rho(theta_i) (must stay < 1)", fontsize=9)
    ax.grid(True, which="both", alpha=0.25)
    ax.legend(fontsize=7)
    name = getattr(material, "name", "material")
    fig.suptitle(title or f"{name}", fontsize=11)
    return _save(fig, path)
