"""The design report: DIR/index.html with the layout to scale, the PST comparison, the optimiser's progress."""
from __future__ import annotations

import html

import numpy as np

LIT, SEEN, BOTH = "#f28e2b", "#4e79a7", "#e15759"


def draw_layout(ax, spec, layout, title):
    """Meridional section to scale: wall, vanes, end plate, detector, field envelope, and on the
    right wall (lit by a beam tilted toward +x) the sections lit at >= E, seen, and both."""
    from matplotlib.patches import Polygon

    R, L, S = spec.tube_radius_mm, spec.tube_length_mm, spec.stop_radius_mm
    w = 1.0
    grey = "0.35"
    for sgn in (-1, 1):
        ax.add_patch(Polygon([(sgn * R, 0), (sgn * (R + w), 0), (sgn * (R + w), L), (sgn * R, L)], color=grey))
        ax.add_patch(Polygon([(sgn * S, -w), (sgn * (R + w), -w), (sgn * (R + w), 0), (sgn * S, 0)], color=grey))
        for v in layout.vanes:
            (zt, rt), (zb, rb) = spec.corners(v)
            ax.add_patch(Polygon([(sgn * rt, zt), (sgn * R, zt), (sgn * R, zb), (sgn * rb, zb)], color="k"))
    ax.plot([-S, S], [0, 0], color="#59a14f", lw=3, label="detector")
    z = np.array([0.0, L])
    for sgn in (-1, 1):
        ax.plot(sgn * spec.envelope_radius_mm(z), z, ":", color="0.4", lw=0.8,
                label="field envelope" if sgn > 0 else None)
    # a ray at E grazing the far entrance rim
    tan_e = spec.tan_exclusion
    z_hit = max(0.0, L - 2 * R / tan_e)
    ax.plot([-R, -R + (L - z_hit) * tan_e], [L, z_hit], "--", color=LIT, lw=0.8, label=f"ray at E = {spec.exclusion_deg:g} deg")
    for bay in layout.bays:
        for interval, colour, dx, label in ((bay.lit_mm, LIT, 2.5, "lit at >= E"), (bay.seen_mm, SEEN, 4.5, "seen by detector"),
                                            (bay.lit_and_seen_mm, BOTH, 6.5, "lit and seen")):
            if interval:
                ax.plot([R + dx, R + dx], interval, color=colour, lw=3, solid_capstyle="butt", label=label)
    handles, labels = ax.get_legend_handles_labels()
    unique = dict(zip(labels, handles))
    ax.legend(unique.values(), unique.keys(), fontsize=6, loc="lower left")
    ax.set_aspect("equal")
    ax.set_xlim(-R - 4, R + 10)
    ax.set_ylim(-3, L + 3)
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("z (mm)")
    ax.set_title(title, fontsize=9)


def _pst_plot(ax, doc):
    series = [("design", "design", "o-"), ("baseline", "evenly spaced", "s--"), ("no_vanes", "no vanes", "^:")]
    if doc["design_source"] != "construction":
        series.insert(1, ("construction", "construction", "d-."))
    for key, label, fmt in series:
        pts = doc["pst"] if key == "design" else doc[key]["pst"]
        x = np.array([p["off_axis_deg"] for p in pts])
        y = np.array([p["pst"] for p in pts])
        e = np.array([p["pst_stderr"] for p in pts])
        pos = y > 0
        ax.errorbar(x[pos], y[pos], yerr=np.minimum(e[pos], 0.999 * y[pos]), fmt=fmt, capsize=3, ms=4, label=label)
    ax.set_yscale("log")
    ax.set_xlabel("off-axis angle (deg)")
    ax.set_ylabel("PST")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("PST (1-sigma bars)", fontsize=10)


def _progress_plot(ax, refinement):
    ok = [e for e in refinement.evaluations if e.objective is not None]
    i = np.array([e.index for e in ok])
    j = np.array([e.objective for e in ok])
    se = np.array([e.objective_stderr for e in ok])
    ax.errorbar(i, j, yerr=se, fmt="o", ms=3, capsize=2, alpha=0.6, label="layout (J +- 1 sigma)")
    ax.step(i, np.minimum.accumulate(j), where="post", color="k", label="best so far")
    ax.axhline(refinement.start_objective, color=LIT, ls="--", lw=1, label="construction")
    ax.set_xlabel("evaluation")
    ax.set_ylabel("J = mean ln PST over " + ", ".join(f"{a:g}" for a in refinement.angles_deg) + " deg")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(f"optimiser ({refinement.rays} rays/angle, common random numbers)", fontsize=10)


def _table(rows, header) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def write_report(out, spec, doc, built, design, baseline, refinement):
    """Write layout.png, pst.png, progress.png (if refined) and index.html into ``out``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from atomicio import write_figure, write_text

    panels = [(built, "construction"), (design, f"design ({doc['design_source']})"),
              (baseline, "evenly spaced baseline")]
    if doc["design_source"] == "construction":
        panels = [panels[0], panels[2]]
    elif doc["design_source"] == "evenly spaced":
        panels = panels[:2]
    aspect = (spec.tube_length_mm + 6) / (2 * spec.tube_radius_mm + 14)
    fig, axes = plt.subplots(1, len(panels), figsize=(3.2 * len(panels), min(3.2 * aspect, 11) + 0.8), dpi=110)
    for ax, (layout, title) in zip(np.atleast_1d(axes), panels):
        draw_layout(ax, spec, layout, f"{title}: {len(layout.vanes)} vanes")
    fig.tight_layout()
    write_figure(fig, out / "layout.png")
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(6, 4), dpi=110)
    _pst_plot(ax, doc)
    fig.tight_layout()
    write_figure(fig, out / "pst.png")
    plt.close(fig)
    images = ["layout.png", "pst.png"]
    if refinement is not None and len(refinement.evaluations) > 1:
        fig, ax = plt.subplots(figsize=(6, 4), dpi=110)
        _progress_plot(ax, refinement)
        fig.tight_layout()
        write_figure(fig, out / "progress.png")
        plt.close(fig)
        images.append("progress.png")

    inputs = doc["inputs"]
    vanes = _table([(k, f"{v['z_mm']:.3f}", f"{v['inner_radius_mm']:.3f}", f"{v['thickness_mm']:g}")
                    for k, v in enumerate(doc["vanes"], 1)], ["vane", "z (mm)", "inner radius (mm)", "thickness (mm)"])
    rows = []
    for d, c, b, n, r in zip(doc["pst"], doc["construction"]["pst"], doc["baseline"]["pst"], doc["no_vanes"]["pst"],
                             doc["ratio_to_baseline"]):
        ratio = "-" if r["ratio"] is None else f"{r['ratio']:.3f} +- {r['ratio_stderr']:.3f}"
        rows.append((f"{d['off_axis_deg']:g}", f"{d['pst']:.3e} +- {d['pst_stderr']:.1e}",
                     f"{c['pst']:.3e} +- {c['pst_stderr']:.1e}", f"{b['pst']:.3e} +- {b['pst_stderr']:.1e}",
                     f"{n['pst']:.3e} +- {n['pst_stderr']:.1e}", ratio))
    pst_table = _table(rows, ["off-axis (deg)", "design PST", "construction PST", "evenly spaced PST", "no vanes PST",
                              "design / evenly"])
    geo = doc["geometry"]
    notes = "".join(f"<li>{html.escape(n)}</li>" for n in doc["construction"]["notes"])
    opt = doc["optimiser"]
    opt_text = ("not run" if opt is None else
                f"{sum(e['objective'] is not None for e in opt['evaluations'])} layouts traced; {opt['stop_reason']}; "
                f"J {opt['start_objective']:.3f} -> {opt['best_objective']:.3f} (1 sigma {opt['start_objective_stderr']:.3f}) "
                f"on the optimiser's own random numbers; the best of many noisy values is biased low, so the "
                f"construction and the refined layout were traced again with fresh numbers and the lower was kept")
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>Vane design</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:2em auto}}table{{border-collapse:collapse}}
td,th{{border:1px solid #ccc;padding:3px 8px;text-align:right}}</style></head><body>
<h1>Vane design: R {spec.tube_radius_mm:g} mm, L {spec.tube_length_mm:g} mm, S {spec.stop_radius_mm:g} mm,
field {spec.field_deg:g} deg, exclusion {spec.exclusion_deg:g} deg</h1>
<p>Coating {html.escape(str(inputs['material']))}; vane thickness {spec.vane_thickness_mm:g} mm, bevel
{spec.bevel_deg:g} deg ({spec.bevel_side}); {doc['pst'][0]['rays']} rays per angle, seed {inputs['seed']};
{doc['seconds']} s. The design is the <b>{doc['design_source']}</b> layout.
Exact geometry: nothing in the field vignettes (margin {geo['vignetting_margin_mm']:.3g} mm);
wall both lit at &ge; E and seen by the detector: {geo['lit_and_seen_mm']:.3g} mm
(evenly spaced: {doc['baseline']['geometry']['lit_and_seen_mm']:.3g} mm).</p>
{('<ul>' + notes + '</ul>') if notes else ''}
<h2>Vanes</h2>{vanes}
<h2>PST</h2><p>PST = {html.escape(doc['pst_definition'])}.</p>{pst_table}
<h2>Optimiser</h2><p>{html.escape(opt_text)}</p>
{''.join(f'<p><img src="{i}" alt="{i}"></p>' for i in images)}
<p>Files: design.json, scene.toml (run <code>straylight pst scene.toml ...</code> on it), design.step.
Method and references: docs/design.md.</p></body></html>
"""
    write_text(out / "index.html", page)
    return out / "index.html"

