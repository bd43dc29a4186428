"""An interactive 3-D view of an instrument as one HTML file that opens in a plain browser.

``write_view3d(path, setup, trace_result, report, off_axis)`` writes a page with everything
inlined (no server, no network): three.js (``straylight/viewer/three-view.min.js``, vendored from
the npm package ``three``, MIT licence), the viewer script (``viewer/view3d.js``), and the data:

- every part as a triangle mesh, coloured by the power it absorbed (or that arrived on it, or one
  colour per part) in the trace at this angle, log scale; the detector in yellow;
- the entrance disk;
- the ranked paths of the path report, each with a few sample rays (:func:`path_samples`), each in its
  own colour (the panel's swatches are the legend), the first five with rays drawn on opening;
- the instrument cut open along its axis (the half toward the camera clipped away; a check box puts it
  back) and the detector marked with a box and a label, so the page opens showing the light.

A person rotates (left drag), zooms (wheel), pans (right drag) and hides parts with the panel's
check boxes. Large assemblies are decimated for the view only (:func:`view_meshes`, VTK's quadric
decimation through pyvista) to about ``max_triangles``; the numbers shown come from the trace,
which used the full meshes.
"""
from __future__ import annotations

import base64
import html
import json
import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

import atomicio

DEFAULT_MAX_TRIANGLES = 150_000
MIN_PART_TRIANGLES = 200  # a part is never decimated below this


@dataclass(frozen=True)
class ViewMesh:
    """One part as drawn: vertices_mm (k, 3) float32, faces (m, 3) uint32; ``triangles_traced``: the trace's count."""

    name: str
    role: str
    vertices_mm: np.ndarray
    faces: np.ndarray
    triangles_traced: int


def view_meshes(scene, max_triangles: int = DEFAULT_MAX_TRIANGLES) -> list[ViewMesh]:
    """The scene's parts for display, decimated so that together they hold about ``max_triangles``.

    Parts are reduced in proportion (each to ``max_triangles / total`` of its triangles, never
    below ``MIN_PART_TRIANGLES``) by quadric decimation (``pyvista.PolyData.decimate``); the
    scene itself is not changed.
    """
    if max_triangles < 1:
        raise ValueError(f"max_triangles must be >= 1, got {max_triangles!r}")
    total = sum(len(p.faces) for p in scene.parts)
    keep = min(1.0, max_triangles / max(total, 1))
    out = []
    for part in scene.parts:
        v, f = np.asarray(part.vertices_mm, dtype=np.float64), np.asarray(part.faces, dtype=np.int64)
        n = len(f)
        target = max(MIN_PART_TRIANGLES, math.ceil(keep * n))
        if target < n:
            v, f = _decimate(v, f, 1.0 - target / n)
        out.append(ViewMesh(part.name, part.role, v.astype(np.float32), f.astype(np.uint32), n))
    return out


def _decimate(vertices_mm, faces, reduction: float):
    """Quadric decimation (vtkQuadricDecimation via pyvista) by the fraction ``reduction`` of triangles."""
    from straylight.viz import _pyvista

    pv = _pyvista(True)
    mesh = pv.PolyData(vertices_mm, np.hstack([np.full((len(faces), 1), 3), faces]).ravel())
    small = mesh.decimate(float(reduction)).triangulate()
    f = small.faces.reshape(-1, 4)[:, 1:]
    return np.asarray(small.points, dtype=np.float64), f


@dataclass(frozen=True)
class PathSample:
    """Sample rays of one ranked path group: ``polylines`` are lists of (k, 3) points in mm."""

    rank: int
    label: str
    fraction: float
    fraction_stderr: float
    polylines: list


def _unit(v):
    return v / max(float(np.linalg.norm(v)), 1e-300)


def path_samples(setup, report, off_axis: float, azimuth: float = 0.0, top: int = 15, per_group: int = 6,
                 n_walks: int = 3000, seed: int = 0) -> list[PathSample]:
    """A few rays drawn for each of the ``top`` groups of a path report (grouped by sequence).

    The rays are the engine's own walks (:func:`straylight.viz.display_walks`: a short analog trace
    with its ray log on), with the engine's own event at each vertex (scatter, or specular: a mirror,
    an interface's reflection or refraction). Each prefix of a walk that scatters on a surface is
    joined to a random point of the detector when nothing blocks that segment (the next-event
    connection the engine makes), and a walk that hits the detector is kept as it is. A ray joins
    the group whose label its sequence of parts and events gives (diffraction is not drawn). Rays
    show where a path runs; their number is not its power (the group's fraction, from the trace, is).
    """
    from straylight.engine.ray_batch import EVENT_SCATTER, EVENT_SPECULAR
    from straylight.paths import sequence_label
    from straylight.intersect import EmbreeIntersector
    from straylight.viz import display_walks

    scene = setup.scene
    det = report.detector
    det_index = scene.part_names.index(det)
    wanted = {r.label: r for r in report.rows[:top]} if report.group_by == "sequence" else {}
    found: dict[str, list] = {k: [] for k in wanted}
    if wanted:
        log, _ = display_walks(setup, off_axis, azimuth, n_rays=n_walks, seed=seed)
        names, roles = scene.part_names, [p.role for p in scene.parts]
        tri_part = scene.triangle_part
        rng = np.random.default_rng([int(seed), 11])
        dpart = scene.part(det)
        dtri = np.asarray(dpart.vertices_mm, dtype=np.float64)[np.asarray(dpart.faces)]
        area = 0.5 * np.linalg.norm(np.cross(dtri[:, 1] - dtri[:, 0], dtri[:, 2] - dtri[:, 0]), axis=1)
        cdf = np.cumsum(area) / area.sum()
        eps = 1e-6 * float(np.ptp(scene.bounds_mm, axis=0).max())
        starts, ends, prefixes, labels = [], [], [], []
        for _, rows in log.rays():
            tris, kinds = log.tri[rows], log.kind[rows]
            pts = np.vstack([log.origin_mm[rows][:1], log.end_mm[rows]])
            events: list[tuple[str, str]] = []
            for j, t in enumerate(tris):
                if t < 0:  # escaped, or bent at an edge
                    break
                part = int(tri_part[t])
                if part == det_index:
                    label = sequence_label(events, det)
                    if label in found and len(found[label]) < per_group:
                        found[label].append(pts[: j + 2])
                    break
                if roles[part] not in ("surface", "mirror"):
                    break
                after = int(kinds[j + 1]) if j + 1 < len(tris) else None  # the engine's event here (None: it ended)
                if roles[part] == "surface" and after in (None, EVENT_SCATTER):  # a scatter vertex, joined to the detector
                    label = sequence_label([*events, (names[part], "scatter")], det)
                    if label in found and len(found[label]) < per_group:
                        n = scene.triangle_normals[t]
                        incoming = _unit(pts[j + 1] - pts[j])
                        starts.append(pts[j + 1])
                        prefixes.append(pts[: j + 2])
                        labels.append(label)
                        ends.append(-n if np.dot(incoming, n) > 0 else n)  # the side the ray came from
                if after not in (EVENT_SCATTER, EVENT_SPECULAR):
                    break
                events.append((names[part], "scatter" if after == EVENT_SCATTER else "specular"))
        if starts:
            p, side = np.array(starts), np.array(ends)
            k = np.minimum(np.searchsorted(cdf, rng.random(len(p)), side="right"), len(cdf) - 1)
            u = rng.random((len(p), 2))
            s = np.sqrt(u[:, 0])
            tri = dtri[k]
            q = tri[:, 0] * (1 - s)[:, None] + tri[:, 1] * (s * (1 - u[:, 1]))[:, None] + tri[:, 2] * (s * u[:, 1])[:, None]
            d = q - p
            dist = np.linalg.norm(d, axis=1)
            d = d / np.maximum(dist, 1e-300)[:, None]
            ok = np.einsum("ij,ij->i", d, side) > 0
            hit_tri, _ = EmbreeIntersector(scene.triangles_mm).intersect(p + eps * side, d)
            ok &= (hit_tri >= 0) & (tri_part[np.maximum(hit_tri, 0)] == det_index)
            for i in np.flatnonzero(ok):
                if len(found[labels[i]]) < per_group:
                    found[labels[i]].append(np.vstack([prefixes[i], q[i]]))
    return [PathSample(r.rank, r.label, float(r.fraction), float(r.fraction_stderr),
                       [np.round(np.asarray(x, dtype=np.float64), 3).tolist() for x in found.get(r.label, [])])
            for r in report.rows[:top]]


def cut_open_faces(mesh: ViewMesh, cut_y_mm: float) -> np.ndarray:
    """The faces the cut-open view keeps: a detector whole; any other part without the triangles lying wholly
    on the camera's side (y > ``cut_y_mm``, the page looks from +y), so the instrument opens toward the viewer."""
    if mesh.role == "detector" or len(mesh.faces) == 0:
        return mesh.faces
    y = np.asarray(mesh.vertices_mm, dtype=np.float64)[np.asarray(mesh.faces, dtype=np.int64), 1]
    return np.ascontiguousarray(mesh.faces[~np.all(y > cut_y_mm, axis=1)])


def _b64(array) -> str:
    return base64.b64encode(np.ascontiguousarray(array).astype(array.dtype.newbyteorder("<")).tobytes()).decode()


def view_data(setup, absorbed_w: dict, incident_w: dict, samples=(), title: str = "",
              max_triangles: int = DEFAULT_MAX_TRIANGLES) -> dict:
    """The JSON the page reads: parts (base64 little-endian float32 / uint32), entrance, paths, bounds."""
    meshes = view_meshes(setup.scene, max_triangles)
    cut_y = float(np.mean(np.asarray(setup.scene.bounds_mm, dtype=float)[:, 1]))
    parts = [{"name": m.name, "role": m.role, "vertices_f32": _b64(m.vertices_mm), "faces_u32": _b64(m.faces),
              "cut_faces_u32": _b64(cut_open_faces(m, cut_y)),
              "triangles": len(m.faces), "triangles_traced": m.triangles_traced,
              "absorbed_w": float(absorbed_w.get(m.name, 0.0)), "incident_w": float(incident_w.get(m.name, 0.0))}
             for m in meshes]
    entrance = None
    if setup.entrance is not None:
        e = setup.entrance
        normal = e.normal if e.normal is not None else setup.beam.axis
        entrance = {"center_mm": [float(x) for x in e.center_mm], "radius_mm": float(e.radius_mm),
                    "normal": [float(x) for x in normal]}
    return {"title": title, "bounds_mm": np.asarray(setup.scene.bounds_mm, dtype=float).tolist(), "parts": parts,
            "entrance": entrance, "paths": [s.__dict__ for s in samples]}


def _asset(name: str) -> str:
    return resources.files("straylight.viewer").joinpath(name).read_text(encoding="utf-8")


def view_page(data: dict) -> str:
    """The standalone HTML page for ``data`` (:func:`view_data`), scripts and data inlined."""
    # every <, > and & as a JSON \u escape: neither "</script>" nor "<!--<script>" (which would hold the parser
    # in the script's escaped state past its end tag) can appear inside the data block
    payload = (json.dumps(data, separators=(",", ":"))
               .replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026"))
    title = html.escape(data.get("title") or "3-D view")
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{title}</title>
<style>
html, body {{ margin: 0; height: 100%; font-family: sans-serif; font-size: 13px; color: #222; }}
#view3d {{ display: flex; height: 100%; }}
#view3d-panel {{ width: 300px; overflow-y: auto; padding: 8px; border-right: 1px solid #ccc; box-sizing: border-box; }}
#view3d-canvas-host {{ flex: 1; position: relative; min-width: 200px; }}
#view3d-canvas-host canvas {{ display: block; }}
.view3d-row {{ display: flex; gap: 4px; align-items: center; white-space: nowrap; cursor: pointer; }}
.view3d-label {{ position: absolute; pointer-events: none; background: rgba(255,255,255,0.85); color: #a000a0;
  font-weight: bold; padding: 1px 4px; border: 1px solid #c000c0; white-space: nowrap; }}
.view3d-swatch {{ display: inline-block; width: 12px; height: 12px; border: 1px solid #888; flex: none; }}
h3 {{ margin: 8px 0 4px; font-size: 13px; }} #view3d-scale, .view3d-note {{ color: #555; font-size: 11px; }}
</style></head><body>
<div id="view3d">
<div id="view3d-panel">
<div><b>{title}</b></div>
<div class="view3d-note">Left drag: rotate; wheel: zoom; right drag: pan.</div>
<h3>Colour</h3>
<select id="view3d-color"><option value="absorbed">absorbed power per part</option>
<option value="incident">incident power per part</option><option value="part">one colour per part</option></select>
<div id="view3d-scale"></div>
<label class="view3d-row"><input type="checkbox" id="view3d-cut" checked> cut open (the half toward you removed)</label>
<h3>Parts (untick to hide)</h3><div id="view3d-parts"></div>
<h3>Ranked stray-light paths (the colour swatch is the ray colour; the main ones are drawn)</h3>
<div id="view3d-paths"></div>
<div class="view3d-note">Sample rays show where a path runs; its share of the detector power is the
percentage (from the trace). Meshes may be decimated for display only.</div>
</div>
<div id="view3d-canvas-host"></div>
</div>
<script>{_asset("three-view.min.js")}</script>
<script type="application/json" id="view3d-data">{payload}</script>
<script>{_asset("view3d.js")}</script>
</body></html>
"""


def write_view3d(path, setup, trace_result, report=None, off_axis: float = 0.0, azimuth: float = 0.0,
                 seed: int = 0, title: str | None = None, max_triangles: int = DEFAULT_MAX_TRIANGLES,
                 top_paths: int = 15) -> Path:
    """Write the interactive view of ``setup`` after ``trace_result`` (a TraceResult at this tilt).

    report : the :class:`~straylight.analyses.paths_report.PathReport` of the same trace (its ranked
        groups get sample rays), or None for parts only.
    """
    # a detector's "absorbed" power is what it detected
    absorbed = {**{k: v.power_w for k, v in trace_result.absorbed.items()},
                **{k: v.power_w for k, v in trace_result.detectors.items()}}
    incident = {k: v.power_w for k, v in trace_result.incident.items()}
    samples = (path_samples(setup, report, off_axis, azimuth, top=top_paths, seed=seed) if report is not None
               else [])
    if title is None:
        title = f"{setup.description}: beam {math.degrees(off_axis):g} deg off axis"
    page = view_page(view_data(setup, absorbed, incident, samples, title, max_triangles))
    path = Path(path)
    atomicio.write_text(path, page)
    return path


def report_section(name: str = "view3d.html") -> str:
    """The index.html block that embeds the view (an iframe of the standalone page, and a link to it)."""
    n = html.escape(name)
    return (f'<h2>Interactive 3-D view</h2>\n<p>The instrument cut open, the main stray-light paths drawn (one colour each, '
            f'legend in the panel), the detector marked. Rotate, zoom, hide parts, tick paths '
            f'(<a href="{n}">open in its own window</a>).</p>\n'
            f'<iframe id="view3d-frame" src="{n}" title="interactive 3-D view" '
            f'style="width:100%; height:640px; border:1px solid #ccc"></iframe>')
