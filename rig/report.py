"""Human-readable diagnosis report: plots, report.md and index.html.

``write_report(diagnosis, out_dir)`` writes, per polarization:

* ``overlay_<pol>.png``: measured BRDF (with its standard error) and the simulation before
  (baseline: material only, nominal rig) and after (selected effects) for every incidence angle;
* ``core_<pol>.png``: the same within 3 deg of specular, where offsets, slit and tilt act;
* ``residuals_<pol>.png``: log10(measured / simulated) against the angle from specular, before
  and after, coloured by region, with the +-1 sigma noise band;

plus ``gaps.png`` (gap per region, before and after) and the score table of the candidates.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

import atomicio
from rig.diagnose import REGION_ORDER, Diagnosis, to_json

REGION_COLOURS = {"specular_core": "tab:red", "shoulder": "tab:orange", "wing": "tab:blue",
                  "grazing": "tab:purple", "near_retro": "tab:green"}


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def _grid(n):
    cols = min(3, n)
    rows = (n + cols - 1) // cols
    return rows, cols


def _plot_overlays(d: Diagnosis, sim_before, sim_after, out: Path, pol: str, core: bool):
    plt = _plt()
    p = d.problem
    angles = [a for a in np.unique(p.theta_i_deg) if np.any((p.theta_i_deg == a) & (p.pol == pol))]
    rows, cols = _grid(len(angles))
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.2 * rows), squeeze=False)
    for ax, ti in zip(axes.flat, angles):
        sel = (p.theta_i_deg == ti) & (p.pol == pol)
        x = p.signed_tr_deg[sel] - (ti if core else 0.0)
        if core:
            sel = sel & (np.abs(p.signed_tr_deg - ti) <= 3.0)
            x = p.signed_tr_deg[sel] - ti
        order = np.argsort(x)
        x = x[order]
        y = p.y[sel][order]
        err = np.nan_to_num(p.sem[sel][order])
        ok = p.usable[sel][order]
        ax.errorbar(x[ok], y[ok], yerr=err[ok], fmt="o", ms=2.5, color="k", lw=0.8, label="measured")
        if (~ok).any():
            ax.plot(x[~ok], np.abs(y[~ok]) + 1e-12, "x", color="0.6", ms=3, label="below noise")
        ax.plot(x, sim_before[sel][order], "-", color="tab:blue", lw=1.0, label="before (baseline)")
        ax.plot(x, sim_after[sel][order], "--", color="tab:red", lw=1.0, label="after (selected)")
        ax.set_yscale("log")
        held = " (held out)" if ti in p.heldout_deg else ""
        ax.set_title(f"theta_i = {ti:g} deg, {pol}{held}", fontsize=9)
        ax.set_xlabel("theta_r - theta_i (deg)" if core else "signed theta_r (deg)", fontsize=8)
        ax.set_ylabel("BRDF (1/sr)", fontsize=8)
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[len(angles):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7)
    fig.tight_layout()
    name = f"{'core' if core else 'overlay'}_{pol}.png"
    atomicio.write_figure(fig, out / name, dpi=110)
    plt.close(fig)
    return name


def _plot_residuals(d: Diagnosis, sim_before, sim_after, out: Path, pol: str):
    plt = _plt()
    p = d.problem
    angles = [a for a in np.unique(p.theta_i_deg) if np.any((p.theta_i_deg == a) & (p.pol == pol))]
    rows, cols = _grid(len(angles))
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.0 * rows), squeeze=False)
    for ax, ti in zip(axes.flat, angles):
        sel = (p.theta_i_deg == ti) & (p.pol == pol) & p.usable
        off = p.signed_tr_deg[sel] - ti
        # symmetric log axis: the core (0.05 deg steps) and the wings (5 deg) on one plot
        x = np.sign(off) * np.log10(1.0 + np.abs(off) / 0.05)
        rb = np.log10(p.y[sel] / sim_before[sel])
        ra = np.log10(p.y[sel] / sim_after[sel])
        sig = p.sigma_log[sel]
        order = np.argsort(x)
        ax.fill_between(x[order], -sig[order], sig[order], color="0.85", label="+-1 sigma noise")
        for region in REGION_ORDER:
            m = p.region[sel] == region
            if m.any():
                ax.plot(x[m], rb[m], "o", ms=3, mfc="none", color=REGION_COLOURS[region], label=f"{region} before")
                ax.plot(x[m], ra[m], ".", ms=4, color=REGION_COLOURS[region], label=f"{region} after")
        ax.axhline(0, color="k", lw=0.5)
        ticks = np.array([-30, -3, -0.3, 0, 0.3, 3, 30])
        ax.set_xticks(np.sign(ticks) * np.log10(1 + np.abs(ticks) / 0.05))
        ax.set_xticklabels([f"{t:g}" for t in ticks], fontsize=7)
        held = " (held out)" if ti in p.heldout_deg else ""
        ax.set_title(f"theta_i = {ti:g} deg, {pol}{held}", fontsize=9)
        ax.set_xlabel("theta_r - theta_i (deg, log-scaled)", fontsize=8)
        ax.set_ylabel("log10(measured / simulated)", fontsize=8)
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[len(angles):]:
        ax.axis("off")
    handles, labels = axes.flat[0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=7, loc="lower center", ncol=6)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    name = f"residuals_{pol}.png"
    atomicio.write_figure(fig, out / name, dpi=110)
    plt.close(fig)
    return name


def _plot_gaps(doc: dict, out: Path):
    plt = _plt()
    rows = doc["regions"]
    labels = [f"{r['name']}\n{r['theta_i_deg']:g} {r['polarization']}{'*' if r['heldout'] else ''}" for r in rows]
    before = [r["gap"] for r in rows]
    after = [r["gap_final"] for r in rows]
    fig, ax = plt.subplots(figsize=(max(6.0, 0.32 * len(rows)), 3.6))
    x = np.arange(len(rows))
    ax.bar(x - 0.2, before, 0.4, label="before", color="tab:blue")
    ax.bar(x + 0.2, after, 0.4, label="after", color="tab:red")
    noise = doc["noise_level"]["train_gap"]
    if noise:
        ax.axhline(noise, color="k", ls=":", lw=1, label="noise level (train)")
    ax.set_xticks(x)
    ax.set_xticklabels(labels, rotation=90, fontsize=6)
    ax.set_ylabel("gap (rms log10, dex)")
    ax.set_title("gap per region, incidence and polarization (* held out)", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    atomicio.write_figure(fig, out / "gaps.png", dpi=110)
    plt.close(fig)
    return "gaps.png"


def _fmt(v, spec=".3f"):
    if v is None:
        return "-"
    if isinstance(v, float):
        return format(v, spec)
    return str(v)


def _markdown(doc: dict, images: list) -> str:
    b, f, nz = doc["baseline"], doc["final"], doc["noise_level"]
    lines = ["# Sim-to-real diagnosis", ""]
    lines.append(f"Measured scan: `{doc.get('measured', '')}`. Gap metric: RMS of log10(measured / simulated) in dex "
                 f"({doc['gap_rule']}).")
    lines.append("")
    lines.append(f"Held-out incidence angles: {', '.join(f'{a:g}' for a in doc['heldout_theta_i_deg']) or 'none'} deg; "
                 f"training: {', '.join(f'{a:g}' for a in doc['train_theta_i_deg'])} deg.")
    lines.append("")
    lines.append("| | held-out gap | training gap |")
    lines.append("|---|---|---|")
    lines.append(f"| before (material fitted through the nominal rig) | {_fmt(b['heldout_gap'])} | {_fmt(b['train_gap'])} |")
    lines.append(f"| after (selected effects) | {_fmt(f['heldout_gap'])} | {_fmt(f['train_gap'])} |")
    lines.append(f"| noise level (gap of a perfect model) | {_fmt(nz['heldout_gap'])} | {_fmt(nz['train_gap'])} |")
    lines.append("")
    sel = doc["selected_effects"]
    if sel:
        parts = []
        for n in sel:
            params = ", ".join(f"{k} = {v:.4g}" for k, v in doc["selected_parameters"][n].items())
            parts.append(f"**{n}** ({params})")
        lines.append("Selected effects, in the order added: " + "; ".join(parts) + ".")
    else:
        lines.append("Selected effects: **none**: no catalogue effect improves both the BIC and the held-out prediction.")
    for c in doc["confounded"]:
        lines.append("")
        lines.append(f"Confounded: {' and '.join(c['effects'])} ({', '.join(c['regions'])}): {c['note']}.")
    lines += ["", "## Candidates (each alone on top of the baseline, best first)", "",
              "| effect | fitted | delta BIC | held-out gap before | after | delta held-out chi2 |",
              "|---|---|---|---|---|---|"]
    for c in doc["candidates"]:
        params = ", ".join(f"{k} = {v:.4g}" for k, v in c["fitted"].items())
        lines.append(f"| {c['name']} | {params} | {c['delta_bic']:.1f} | {_fmt(c['heldout_gap_before'])} | "
                     f"{_fmt(c['heldout_gap_after'])} | {_fmt(c.get('delta_heldout_chi2'), '.1f')} |")
    lines += ["", "## Regions", "", "| region | theta_i | pol | points | held out | gap before | bias before | "
              "effect blamed | gap after | bias after |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in doc["regions"]:
        lines.append(f"| {r['name']} | {r['theta_i_deg']:g} | {r['polarization']} | {r['n_points']} | "
                     f"{'yes' if r['heldout'] else ''} | {r['gap']:.3f} | {r['bias']:+.3f} | {r['effect'] or '-'} | "
                     f"{r['gap_final']:.3f} | {r['bias_final']:+.3f} |")
    lines += ["", "## Plots", ""]
    for img in images:
        lines.append(f"![{img}]({img})")
        lines.append("")
    return "\n".join(lines) + "\n"


def _html(markdown_text: str, images: list) -> str:
    """A self-contained page: the report's Markdown rendered by markdown-it-py (CommonMark with
    GFM tables: code spans, lists, links, emphasis), the plots as images beside it."""
    from markdown_it import MarkdownIt

    body = MarkdownIt("commonmark", {"html": False}).enable("table").render(markdown_text)
    return ("<!doctype html><html><head><meta charset='utf-8'><title>Sim-to-real diagnosis</title>"
            "<style>body{font-family:sans-serif;max-width:1200px;margin:auto}table{border-collapse:collapse;"
            "font-size:12px}td,th{border:1px solid #ccc;padding:2px 6px}img{max-width:100%}</style></head><body>\n"
            + body + "</body></html>\n")


def write_report(d: Diagnosis, out_dir, doc: dict | None = None) -> Path:
    """Write the plots, report.md, index.html and diagnosis.json into ``out_dir``; returns it."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    doc = doc if doc is not None else to_json(d)
    p = d.problem
    sim_before = p.predict(d.baseline.model)
    sim_after = p.predict(d.final.model)
    images = []
    for pol in ("s", "p", "u"):
        if np.any(p.pol == pol):
            images.append(_plot_overlays(d, sim_before, sim_after, out, pol, core=False))
            images.append(_plot_overlays(d, sim_before, sim_after, out, pol, core=True))
            images.append(_plot_residuals(d, sim_before, sim_after, out, pol))
    images.append(_plot_gaps(doc, out))
    md = _markdown(doc, images)
    atomicio.write_text(out / "report.md", md)
    atomicio.write_text(out / "index.html", _html(md, images))
    atomicio.write_json(out / "diagnosis.json", doc)
    return out
