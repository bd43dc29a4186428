"""The result plots' one-pass tight layout gives matplotlib's own ``tight_layout`` margins."""
import numpy as np
import pytest

from straylight.analyses.types import _tight_layout


def _figure(log_y: bool, title: str, legend: bool):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7, 4.5), dpi=120)
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    x = np.array([0.0, 5.0, 20.0, 60.0])
    y = np.array([3e-2, 4e-4, 4.9e-5, 2e-7])
    ax.errorbar(x, y, yerr=0.05 * y, fmt="o-", capsize=3, label="azimuth 0 deg")
    if log_y:
        ax.set_yscale("log")
    ax.set_xlabel("off-axis angle (deg)")
    ax.set_ylabel("PST = E_detector / E_input")
    ax.set_title(title, fontsize=10)
    if legend:
        ax.legend(fontsize=8)
    return fig


@pytest.mark.parametrize("log_y, title, legend", [(True, "Point source transmittance (1-sigma bars)", True),
                                                  (False, "a much longer title " * 3, False)])
def test_one_pass_layout_gives_matplotlibs_margins(log_y, title, legend):
    ours, theirs = _figure(log_y, title, legend), _figure(log_y, title, legend)
    _tight_layout(ours)
    theirs.tight_layout()
    got = ours.subplotpars
    want = theirs.subplotpars
    for side in ("left", "right", "bottom", "top"):
        assert getattr(got, side) == pytest.approx(getattr(want, side), abs=1e-12), side
    assert (got.left, got.bottom) != (0.125, 0.11)  # laid out, not matplotlib's defaults
