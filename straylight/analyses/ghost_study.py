"""The study's ghost step: a scene with a lens or a window gets its ghost table in the report (CONTRACTS 8.4).

A study of an imported lens (``straylight optics import`` then ``straylight study``) is what an engineer runs
first on it, and the ghost table is the first thing asked of a lens: so the study runs the ``ghosts`` command's
analysis on axis (order 2, the command's defaults) when the scene's materials include a dielectric, writes
ghosts.csv / ghosts.json / ghosts.md / ghosts.png beside the other results, and the report gets a section.
A scene the analysis refuses (a mirror system: no ghost; no design path to the detector) is said in the
section and in results.json, not an error of the study.
"""
from __future__ import annotations

import html

#: ghosts listed in the report's table (ghosts.csv and ghosts.md have them all)
REPORT_ROWS = 10


def has_lenses(materials) -> bool:
    """Whether any of ``materials`` (name -> model) is a smooth dielectric: a lens or window to ghost."""
    from materials.smooth import Dielectric

    return any(isinstance(getattr(m, "smooth", None), Dielectric) for m in materials.values())


def ghost_step(scene_path, setup, out_dir, seed: int = 0) -> dict:
    """The ghost table of ``scene_path`` (a scene :func:`has_lenses`) at its detector on axis, written into
    ``out_dir``; its JSON (the ``ghosts.json`` document), or ``{"skipped": reason}`` when the analysis refuses
    the scene."""
    from straylight.analyses.ghost_trace import GhostError, ghosts, write_table

    try:
        table = ghosts(scene_path, order=2, field_deg=0.0, detector=setup.detector, seed=seed)
    except GhostError as exc:
        return {"skipped": str(exc)}
    write_table(table, out_dir)
    return table.to_json_dict()


def _cell(x, fmt: str) -> str:
    return "-" if x is None else format(x, fmt)


def report_section(doc: dict | None) -> str:
    """The report's HTML section from :func:`ghost_step`'s result ("" when the study had no lens)."""
    if doc is None:
        return ""
    if "skipped" in doc:
        return f"<h2>Ghosts</h2>\n<p>No ghost table: {html.escape(doc['skipped'])}.</p>"
    rows = "".join(
        f"<tr><td>{k}</td><td>{html.escape(' > '.join(g['surfaces']))}</td><td>{_cell(g['fraction_of_nominal'], '.3e')}"
        f"</td><td>{_cell(g['stderr_w'] / g['power_w'] if g['power_w'] else None, '.1%')}</td>"
        f"<td>{_cell(g['focus_mm'], '.4g')}</td><td>{_cell(g['radius_mm'], '.4g')}</td>"
        f"<td>{_cell(g['peak_ratio'], '.3e')}</td></tr>"
        for k, g in enumerate(doc["ghosts"][:REPORT_ROWS], start=1))
    more = len(doc["ghosts"]) - REPORT_ROWS
    return f"""<h2>Ghosts (order {doc['order']}, on axis)</h2>
<figure><img src="ghosts.png" alt="ghost irradiance maps on the detector" style="max-width:100%"><figcaption>The
nominal image and the strongest ghosts on the detector {html.escape(doc['detector'])} (every path with two reflections
at lens surfaces, traced by splitting; docs/ghosts.md).</figcaption></figure>
<table><tr><th>rank</th><th>surfaces</th><th>of nominal</th><th>1 sigma</th><th>focus (mm)</th><th>radius (mm)</th>
<th>peak ratio</th></tr>{rows}</table>
<p>{f'{more} more in ' if more > 0 else 'Numbers in '}<a href="ghosts.csv">ghosts.csv</a> and
<a href="ghosts.md">ghosts.md</a>; focus: where the ghost's bundle is narrowest, from the detector along the light
(&lt; 0: before it); peak ratio: its peak irradiance over the nominal image's.</p>"""


def markdown_lines(doc: dict | None) -> list[str]:
    """The report.md section from :func:`ghost_step`'s result (none when the study had no lens)."""
    if doc is None:
        return []
    if "skipped" in doc:
        return ["## Ghosts", "", f"No ghost table: {doc['skipped']}.", ""]
    return ["## Ghosts", "", "![ghosts](ghosts.png)", "", "The whole table: [ghosts.md](ghosts.md), "
            "[ghosts.csv](ghosts.csv).", ""]
