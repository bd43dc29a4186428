"""The report of ``design baffles``: DIR/index.html (layout section, PST before/after, obscuration
budget, direct-path check) and DIR/view.html (the interactive 3-D view, straylight.view3d)."""
from __future__ import annotations

import html
import math

import numpy as np

import atomicio


def _plot(out, design):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.3))
    for key, label, fmt in (("pst_before", "before (no shields)", "s--"), ("pst_after", "after (designed shields)", "o-")):
        pts = design[key]
        x = np.array([p["off_axis_deg"] for p in pts])
        y = np.array([p["pst"] for p in pts])
        e = np.array([p["pst_stderr"] for p in pts])
        pos = (y > 0) & (x > 0)
        ax.errorbar(x[pos], y[pos], yerr=np.minimum(e[pos], 0.999 * y[pos]), fmt=fmt, capsize=3, ms=4, label=label)
    ax.axvline(2 * design["field_deg"], color="0.5", ls=":", lw=0.8, label="2 x half-field")
    ax.set_yscale("log")
    ax.set_xlabel("off-axis angle (deg)")
    ax.set_ylabel("PST")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    atomicio.write_figure(fig, out / "pst.png", dpi=110)
    plt.close(fig)


def _row(cells):
    return "<tr>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>"


def write_report(out, design, setup_after, tel) -> None:
    """DIR/pst.png, DIR/index.html and DIR/view.html."""
    _plot(out, design)
    pst_rows = "".join(_row([f"{b['off_axis_deg']:.3g}", f"{b['pst']:.3e} &plusmn; {b['pst_stderr']:.1e}",
                             f"{a['pst']:.3e} &plusmn; {a['pst_stderr']:.1e}"])
                       for b, a in zip(design["pst_before"], design["pst_after"]))
    dc = design["direct_check"]
    direct_rows = "".join(_row([f"{b['off_axis_deg']:.3g}", f"{b['direct_w']:.3e}", f"{a['direct_w']:.3e}",
                                    f"{b['detector_w']:.3e}", f"{a['detector_w']:.3e}"])
                          for b, a in zip(dc["before"], dc["after"]))
    baffle_rows = "".join(_row([html.escape(p["name"]), p["type"], p["shape"],
                                ", ".join(f"{k} {v:.4g}" for k, v in p.items() if k.endswith("_mm") and
                                          isinstance(v, float))]) for p in design["baffles"])
    thr = dc["on_axis_throughput_ratio"]
    field_rows = "".join(_row([f"throughput after / before at {f['off_axis_deg']:.3g} deg (trace, perfect mirrors)",
                               "n/a (nothing on the image before)" if f["throughput_ratio"] is None
                               else f"{f['throughput_ratio']:.4f}"]) for f in dc.get("field", []))
    warn_note = "".join(f"<p><b>Warning:</b> {html.escape(w)}.</p>" for w in design.get("warnings", []))
    sh = design.get("sunshade")
    shade_note = "" if not sh else (
        f"<p>No skirt within the allowed obscuration closes every direct path: the widest that fits leaves lines "
        f"open at {sh['stops_angles_deg'][0]:.2f}-{sh['stops_angles_deg'][1]:.2f} deg, which the sunshade "
        f"(radius {sh['radius_mm']:.4g} mm, {sh['length_mm']:.4g} mm long, clear of the field's beam) stops; "
        f"the check below includes those angles.</p>")
    page = f"""<!DOCTYPE html><html><head><meta charset="utf-8"><title>Telescope baffles</title></head><body>
<h1>Light shields of the two-mirror telescope</h1>
<p>Primary <b>{html.escape(tel.primary)}</b>, secondary <b>{html.escape(tel.secondary)}</b>, image
<b>{html.escape(tel.image)}</b>; half-field {design['field_deg']:g} deg. <a href="view.html">3-D view</a>.
STEP: {html.escape(str(design['step']))}.</p>
{warn_note}
<h2>Obscuration budget (fraction of the on-axis aperture area)</h2>
<table border=1 cellpadding=3>
{_row(['without shields (secondary, hole)', f"{design['obscuration_before']:.4f}"])}
{_row(['with shields', f"{design['obscuration_after']:.4f}"])}
{_row(['added by the shields', f"{design['obscuration_added']:.4f} (allowed {design['max_added_obscuration']:g})"])}
{_row(['on-axis throughput after / before (trace, perfect mirrors)', 'n/a' if thr is None else f'{thr:.4f}'])}
{field_rows}
</table>
<h2>Shields</h2><table border=1 cellpadding=3><tr><th>part</th><th>type</th><th>shape</th><th>dimensions (mm)</th></tr>
{baffle_rows}</table>
{shade_note}
<h2>Direct-path check (perfect mirrors, all else absorbing): power on the image, W</h2>
<p>Direct: paths that did not reflect from the primary and then the secondary. All: every path (at 2F the
edge of the nominal image may still fall on the image disk).</p>
<table border=1 cellpadding=3><tr><th>angle (deg)</th><th>direct before</th><th>direct after</th><th>all before</th>
<th>all after</th></tr>{direct_rows}</table>
<p>{'No direct path: zero power at every angle from 2F to 10 deg.' if dc['blocked'] else
    '<b>Some power still reaches the image directly.</b>'}</p>
<h2>PST with the scene's materials</h2><img src="pst.png" width="60%">
<table border=1 cellpadding=3><tr><th>angle (deg)</th><th>PST before</th><th>PST after</th></tr>{pst_rows}</table>
<p>{design['rays']} rays per angle, seed {design['seed']}. Method: docs/baffles.md.</p>
</body></html>"""
    atomicio.write_text(out / "index.html", page)
    from straylight.trace import trace
    from straylight.view3d import write_view3d

    a = math.radians(max(2 * design["field_deg"], 1.0))
    res = trace(setup_after.scene, [setup_after.beam.source(a)], 5_000, seed=design["seed"],
                materials=setup_after.materials)
    write_view3d(out / "view.html", setup_after, res, None, a, title="designed shields")
