"""Fit figure: one panel per (incidence angle, polarization), log BRDF axis, labelled with units."""
import numpy as np
from matplotlib.image import imread

from materials.fit import fit
from materials.plots import plot_fit
from materials.scan import make_scan


def test_plot_fit_writes_png_with_s_and_p_side_by_side(tmp_path):
    tr = np.tile(np.linspace(-80, 80, 17), 4)
    ti = np.repeat([20.0, 60.0], 34)
    pol = np.tile(np.repeat(["s", "p"], 17), 2)
    brdf = 0.03 / np.pi * (1 + 0.01 * np.cos(np.radians(tr)))
    brdf[0] = np.nan  # flagged points are skipped, not plotted at zero
    scan = make_scan(wavelength_nm=532.0, polarization=pol, theta_i_deg=ti, theta_r_deg=tr,
                     brdf_per_sr=brdf, brdf_std_per_sr=1e-4, n_repeats=3)
    res = fit(scan, "lambertian", n_starts=1)
    path = plot_fit(scan, res, tmp_path / "f.png")
    img = imread(path)
    assert img.shape[1] > img.shape[0] / 2  # two columns (s, p) for two rows of incidence angles
    assert img[..., :3].std() > 0.05  # not blank
