"""Draws docs/img/bsdf_conventions.png: the angles of the Zemax/Radiant tabular BSDF and of FRED's
tabulated BSDF in this project's sample frame (docs/bsdf-files.md). Run: python docs/img/make_bsdf_conventions.py"""
from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

OUT = Path(__file__).with_name("bsdf_conventions.png")


def main() -> Path:
    fig, (a1, a2, a3) = plt.subplots(1, 3, figsize=(15, 5.2))
    ti = math.radians(35.0)
    # (1) the plane of incidence, side view
    a1.set_title("plane of incidence (x-z), CONTRACTS 1")
    a1.plot([-1.1, 1.1], [0, 0], "k-", lw=2)
    a1.annotate("", xy=(0, 1.15), xytext=(0, 0), arrowprops=dict(arrowstyle="->"))
    a1.text(0.03, 1.1, "z = normal")
    a1.annotate("", xy=(0, 0), xytext=(-math.sin(ti), math.cos(ti)), arrowprops=dict(arrowstyle="->", color="C0"))
    a1.text(-math.sin(ti) - 0.15, math.cos(ti) + 0.05, "incident\n(phi_i = 180)", color="C0")
    a1.annotate("", xy=(math.sin(ti), math.cos(ti)), xytext=(0, 0), arrowprops=dict(arrowstyle="->", color="C3"))
    a1.text(math.sin(ti) + 0.02, math.cos(ti), "specular\n= Zemax AngleOfIncidence\n= FRED theta_spec", color="C3")
    for r, c in ((25, "C2"), (-40, "C2")):
        t = ti + math.radians(-r)
        a1.annotate("", xy=(math.sin(t), math.cos(t)), xytext=(0, 0),
                    arrowprops=dict(arrowstyle="->", color=c, alpha=0.6))
    a1.text(0.05, 0.5, "Zemax: azimuth 0 =\nfrom specular toward\nthe normal", color="C2", fontsize=8)
    a1.annotate("", xy=(-math.sin(0.5), -math.cos(0.5)), xytext=(0, 0), arrowprops=dict(arrowstyle="->", color="C4"))
    a1.text(-0.9, -0.75, "BTDF: radial from the directly\ntransmitted ray, mirrored above", color="C4", fontsize=8)
    a1.text(0.45, -0.25, "x: theta_r > 0 (phi_r = 0)", fontsize=8)
    a1.text(-1.05, -0.25, "theta_r < 0 (phi_r = 180)", fontsize=8)
    a1.set_xlim(-1.2, 1.6)
    a1.set_ylim(-1.0, 1.3)
    a1.set_aspect("equal")
    a1.axis("off")
    # (2) the projected disk: beta plane, specular-centred coordinates
    a2.set_title("projected disk (beta = sin theta_r (cos phi_r, sin phi_r))")
    a2.add_patch(plt.Circle((0, 0), 1, fill=False))
    b0 = math.sin(ti)
    a2.plot([b0], [0], "o", color="C3")
    a2.text(b0 - 0.1, -0.25, "beta0 (specular)", color="C3")
    s = np.array([math.sin(ti), 0.0, math.cos(ti)])
    e1 = np.array([-math.cos(ti), 0.0, math.sin(ti)])
    e2 = np.array([0.0, -1.0, 0.0])
    for rad in (10, 20, 30, 45, 60, 90):
        a = np.radians(np.linspace(0, 360, 181))
        w = np.cos(math.radians(rad)) * s + np.sin(math.radians(rad)) * (np.cos(a)[:, None] * e1 + np.sin(a)[:, None] * e2)
        up = w[:, 2] > 0
        a2.plot(np.where(up, w[:, 0], np.nan), np.where(up, w[:, 1], np.nan), "C2-", lw=0.7)
        if rad in (20, 45):
            a2.text(w[0, 0] - 0.05, 0.02, f"R = {rad}", color="C2", fontsize=7)
    for az, lab in ((0, "A = 0 (toward normal)"), (90, "A = 90 (-y)"), (180, "A = 180"), (270, "A = 270 (+y)")):
        w = np.cos(math.radians(30)) * s + np.sin(math.radians(30)) * (math.cos(math.radians(az)) * e1 + math.sin(math.radians(az)) * e2)
        a2.annotate("", xy=(w[0], w[1]), xytext=(b0, 0), arrowprops=dict(arrowstyle="->", color="C1"))
        dy = {0: -0.12, 180: 0.06}.get(az, 0.03)
        a2.text(w[0] - (0.35 if az == 0 else 0.0), w[1] + dy, lab, color="C1", fontsize=8)
    a2.text(-0.95, -0.9, "FRED: a = sin f sin theta (y), b = cos f sin theta (x);\n"
            "interpolation in beta - beta0 (both formats here)", fontsize=8)
    a2.set_xlabel("beta_x (specular half-plane to the right)")
    a2.set_ylabel("beta_y")
    a2.set_aspect("equal")
    a2.set_xlim(-1.1, 1.1)
    a2.set_ylim(-1.1, 1.1)
    # (3) sample rotation on a part
    a3.set_title("SampleRotation rho on a part (top view)")
    a3.add_patch(plt.Rectangle((-1, -1), 2, 2, fill=False))
    a3.annotate("", xy=(0.9, 0), xytext=(0, 0), arrowprops=dict(arrowstyle="->", lw=2))
    a3.text(0.7, -0.15, "part +x\n(= sample X)")
    a3.annotate("", xy=(0, 0.9), xytext=(0, 0), arrowprops=dict(arrowstyle="->", lw=2))
    a3.text(0.03, 0.85, "part +y")
    rho = math.radians(30)
    spec_az = rho + math.pi / 2
    a3.plot([-1.3 * math.cos(spec_az), 1.3 * math.cos(spec_az)], [-1.3 * math.sin(spec_az), 1.3 * math.sin(spec_az)],
            "C3--")
    a3.annotate("", xy=(0.8 * math.cos(rho), 0.8 * math.sin(rho)), xytext=(0, 0),
                arrowprops=dict(arrowstyle="->", color="C0"))
    a3.text(0.8 * math.cos(rho), 0.8 * math.sin(rho) + 0.05, "normal of the plane\nof incidence", color="C0",
            fontsize=8)
    a3.text(-1.25, 1.1, "plane of incidence (dashed): specular azimuth = rho + 90 deg\n"
            "rho = 30 deg shown; rho = 0: light in the part's y-z plane", fontsize=8)
    a3.set_xlim(-1.4, 1.4)
    a3.set_ylim(-1.4, 1.4)
    a3.set_aspect("equal")
    a3.axis("off")
    fig.tight_layout()
    fig.savefig(OUT, dpi=90)
    return OUT


if __name__ == "__main__":
    print(main())
