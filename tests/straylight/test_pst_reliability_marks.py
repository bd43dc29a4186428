"""Error bars a user can trust: where the VOV says a PST point's error estimate is not
reliable, or a cap stopped it before its target, the plot, the study's table and the pst command
say so (pst.json / pst.csv carry the ``flags`` of straylight.analyses.types.point_flags); and the
default study traces to a target error within a time budget, not a fixed ray count."""
import argparse
import math

import numpy as np

from straylight.analyses.types import PstResult


def _result(vov, stop):
    n = len(vov)
    ones = np.ones(n)
    return PstResult(off_axis_deg=np.arange(n) * 10.0, azimuth_deg=np.zeros(n), pst=ones * 1e-5,
                     pst_stderr=ones * 1e-7, entrance_ratio=ones, entrance_ratio_stderr=ones * 0.01,
                     detector_w=ones, detector_stderr_w=ones * 0.01, seconds=ones, rays=1000, seed=0, nee=True,
                     detector="det", detector_area_mm2=1.0, beam_power_w=1.0, point_rays=np.full(n, 1000),
                     diagnostics=[{"vov": v, "rel_error_of_error": 0.1, "max_chunk_share": 0.1, "stop_reason": s,
                                   "rounds": 1} for v, s in zip(vov, stop)],
                     precision={"target_rel_error": 0.02})


def _labels(ax):
    return ax.get_legend_handles_labels()[1]


def test_plot_marks_points_whose_error_bar_is_not_reliable():
    import matplotlib

    matplotlib.use("Agg")
    bad = _result([0.01, 0.4, 0.02], ["target", "max_seconds", "target"]).plot()
    assert any("NOT reliable" in lab for lab in _labels(bad))
    good = _result([0.01, 0.05, 0.02], ["target"] * 3).plot()
    assert not any("NOT reliable" in lab for lab in _labels(good))
    # the marker sits on the flagged point only
    line = [h for h, lab in zip(*bad.get_legend_handles_labels()) if "NOT reliable" in lab][0]
    assert list(line.get_xdata()) == [10.0]


def test_plot_labels_the_log_axis_in_plain_text_with_the_same_values():
    """The PST plot's log-axis tick labels are matplotlib's own, written without mathtext: 4x10^-5
    as 4×10⁻⁵ (the labels' values checked against the tick positions, not against the formatter)."""
    import matplotlib

    matplotlib.use("Agg")
    from straylight.analyses.types import plain_log_label

    assert plain_log_label(r"$\mathdefault{10^{-5}}$") == "10\u207b\u2075"
    assert plain_log_label(r"$\mathdefault{4\times10^{-5}}$") == "4\u00d710\u207b\u2075"
    assert plain_log_label(r"$\mathdefault{10^{12}}$") == "10\u00b9\u00b2"
    assert plain_log_label("") == ""
    ax = _result([0.01, 0.02], ["target"] * 2).plot()  # one decade or less: minor ticks labelled too
    ax.figure.canvas.draw()
    digits = str.maketrans("\u2070\u00b9\u00b2\u00b3\u2074\u2075\u2076\u2077\u2078\u2079\u207b\u2212",
                           "0123456789--")
    shown = 0
    for tick in ax.yaxis.get_major_ticks() + ax.yaxis.get_minor_ticks():
        text = tick.label1.get_text()
        assert "$" not in text
        if text:  # "m×10⁻ᵏ" or "10⁻ᵏ" -> m * 10**-k, the tick's own position
            mant, _, power = text.partition("\u00d7") if "\u00d7" in text else ("1", "", text)
            value = float(mant) * 10.0 ** int(power[2:].translate(digits))
            assert math.isclose(value, tick.get_loc(), rel_tol=1e-9)
            shown += 1
    assert shown >= 2


def test_study_table_and_warning_name_the_unreliable_points():
    from straylight.analyses.report import PST_HEADER, _pst_reliability_note, _pst_table_rows

    res = _result([0.01, 0.4, 0.02], ["target", "target", "max_rays"])
    rows = _pst_table_rows(res, [])
    col = PST_HEADER.index("error bar reliable?")
    assert [r[col] for r in rows] == ["yes", "NO: VOV 0.4 > 0.1", "NO: stopped by max_rays before the target"]
    note = _pst_reliability_note(res)
    assert "10, 20 deg" in note and "not reliable" in note
    assert _pst_reliability_note(_result([0.01, 0.02], ["target", "target"])) == ""


def _study_args(argv):
    from straylight.cli.main import build_parser

    return build_parser().parse_args(["study", "--out", "x", *argv])


def test_default_study_traces_to_a_target_within_a_ray_budget():
    from straylight.cli.pst import precision_from_args
    from straylight.cli.study import DEFAULT_POINT_RAYS, DEFAULT_RAYS, DEFAULT_TARGET_REL_ERROR, default_precision

    args = _study_args([])
    default_precision(args)
    p = precision_from_args(args)
    assert (p.target_rel_error, p.max_rays, args.rays) == (DEFAULT_TARGET_REL_ERROR, DEFAULT_POINT_RAYS, DEFAULT_RAYS)
    assert p.max_seconds == float("inf")  # no wall cap by default: the same seed, the same numbers under any load
    fixed = _study_args(["--rays", "5000"])  # asked for rays: a fixed count, as before
    default_precision(fixed)
    assert precision_from_args(fixed) is None and fixed.rays == 5000
    budget = _study_args(["--max-seconds", "3"])
    default_precision(budget)
    assert precision_from_args(budget).max_seconds == 3.0
    assert isinstance(args, argparse.Namespace)
