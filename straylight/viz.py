"""Pictures: the scene in 3-D (pyvista) with traced ray paths, and detector irradiance maps (matplotlib).

3-D views render off screen when a PNG path is given (or no display exists) and open an
interactive window otherwise. Off screen, VTK needs no X server here: with no ``DISPLAY``
the EGL render window is selected (Mesa's llvmpipe works on machines without a GPU).
The scene is drawn cut away (the half y > 0 removed) so the inside of a tube shows.

Ray paths for a picture come from :func:`trace_ray_paths`: a short trace of the engine itself
with its ray log on (straylight.engine.ray_log), so the drawn rays follow the same physics as the
numbers (refraction through lenses and windows, mirrors, diffraction): one walk, not a copy.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

import atomicio

PART_COLORS = ("#4c72b0", "#dd8452", "#55a868", "#c44e52", "#8172b2", "#937860", "#da8bc3", "#8c8c8c",
               "#ccb974", "#64b5cd")


def _pyvista(off_screen: bool):
    if off_screen and not os.environ.get("DISPLAY"):
        # no X server: go straight to EGL instead of letting VTK try X first (and warn)
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    import pyvista as pv

    return pv


def has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def part_polydata(part):
    """pyvista PolyData of one ``geometry.Part`` (vertices in mm)."""
    pv = _pyvista(True)
    faces = np.hstack([np.full((len(part.faces), 1), 3), part.faces]).ravel()
    return pv.PolyData(part.vertices_mm, faces)


def display_walks(setup, off_axis: float, azimuth: float = 0.0, n_rays: int = 200, seed: int = 0,
                  max_events: int = 6):
    """(ray log, start weight W): ``n_rays`` rays of the setup's beam at (``off_axis``, ``azimuth``),
    rad, traced by the engine with its ray log on (``straylight.engine.ray_log.RayLog``): an analog
    walk (no next-event estimation, no roulette) of at most ``max_events`` events. The rays the
    pictures (:func:`trace_ray_paths`) and the 3-D view (straylight.view3d) draw."""
    import warnings

    from straylight.run_checks import TruncationWarning
    from straylight.trace import EstimatorOptions, OutputOptions, PhysicsOptions, TraceOptions, trace

    options = TraceOptions(estimator=EstimatorOptions(nee=False, rr_threshold=0.0),
                           output=OutputOptions(ray_log=int(n_rays)), physics=PhysicsOptions(max_events=int(max_events)))
    with warnings.catch_warnings():  # a drawing stops its rays after max_events on purpose: not a finding
        warnings.simplefilter("ignore", TruncationWarning)
        res = trace(setup.scene, [setup.beam.source(off_axis, azimuth)], int(n_rays), seed=int(seed),
                    materials=setup.materials, options=options)
    assert res.ray_log is not None  # ray_log > 0 asked for it
    return res.ray_log, res.emitted_w / int(n_rays)  # every ray's weight as it leaves the beam


def trace_ray_paths(setup, off_axis: float, azimuth: float = 0.0, n_rays: int = 200, seed: int = 0,
                    max_events: int = 6, min_weight: float = 1e-4, with_triangles: bool = False):
    """Rays for display: the engine's own walk (:func:`display_walks`), so a drawn ray refracts,
    reflects and bends as the traced ones do.

    Returns a list of (points (k, 3) mm, weights (k - 1,) relative power on each segment,
    reached_detector bool); with ``with_triangles``, a fourth item: the triangle hit at each vertex
    after the first ((j,) int; -1 for an escaping ray's stub, -2 for a bend at a diffracting edge).
    A path is drawn up to its first segment whose relative power is below ``min_weight``.
    """
    from straylight.engine.ray_log import SEGMENT_ESCAPE

    if int(n_rays) <= 0:
        return []
    log, start_w = display_walks(setup, off_axis, azimuth, n_rays, seed, max_events)
    stub_mm = 0.3 * float(np.ptp(np.asarray(setup.scene.bounds_mm)[:, 2]))  # escaping rays: a short stub
    paths = []
    for _, rows in log.rays():
        w = log.weight_w[rows] / start_w
        k = int(np.argmax(w <= min_weight)) if (w <= min_weight).any() else len(w)  # segments drawn
        if k == 0:
            continue
        tri = log.tri[rows][:k]
        end = log.end_mm[rows][:k]
        escaped = tri == SEGMENT_ESCAPE
        end = np.where(escaped[:, None], end + stub_mm * log.direction[rows][:k], end)
        points = np.vstack([log.origin_mm[rows][:1], end])
        reached = bool(log.detector[rows][:k].any())
        paths.append((points, w[:k].copy(), reached, *((tri.astype(np.int64),) if with_triangles else ())))
    return paths


LEGEND_WIDTH = 0.2  # fraction of the picture's width the part legend takes, at its right edge


def _leave_room_right(pl, fraction: float, window_size) -> None:
    """Move a parallel-projection camera so that the scene fits in the left ``1 - fraction`` of the picture
    (the legend's strip stays free of parts and rays)."""
    cam = pl.camera
    aspect = window_size[0] / window_size[1]
    scale = cam.parallel_scale / (1.0 - fraction)  # the scene's width now fits the narrower strip
    cam.parallel_scale = scale
    pos, focal, up = (np.asarray(x, dtype=float) for x in (cam.position, cam.focal_point, cam.up))
    right = np.cross(focal - pos, up)
    right /= np.linalg.norm(right)
    shift = right * fraction * scale * aspect  # half-width is scale * aspect: move the view right by fraction of it
    cam.position = tuple(pos + shift)
    cam.focal_point = tuple(focal + shift)


def render_scene(scene, path=None, *, color_by: str = "part", absorbed_w: dict | None = None, ray_paths=None,
                 cutaway: bool = True, window_size=(1200, 800), title: str | None = None, camera=None):
    """Draw the scene (and ray paths); write a PNG to ``path`` or open a window.

    color_by : "part" (one colour per part, legend) or "absorbed" (parts coloured by
        ``absorbed_w[part]``, log scale, with a colour bar)
    ray_paths : output of :func:`trace_ray_paths`; segments coloured by log10 relative power,
        paths that reach a detector drawn thicker in red
    Returns the path written (or None after an interactive session).
    """
    if color_by not in ("part", "absorbed"):
        raise ValueError(f"color_by must be 'part' or 'absorbed', got {color_by!r}")
    if color_by == "absorbed" and absorbed_w is None:  # {} is a scene where nothing absorbs
        raise ValueError("color_by='absorbed' needs absorbed_w {part: watts}")
    absorbed = absorbed_w or {}
    off_screen = path is not None or not has_display()
    pv = _pyvista(off_screen)
    pl = pv.Plotter(off_screen=off_screen, window_size=tuple(window_size))
    pl.set_background("white")
    legend = []
    bar_shown = False
    if color_by == "absorbed":
        vals = np.array([v for v in absorbed.values() if v > 0])
        lo, hi = (np.log10(vals.min()), np.log10(vals.max())) if len(vals) else (-12.0, 0.0)
        if hi - lo < 1e-6:
            lo -= 1
    for i, part in enumerate(scene.parts):
        mesh = part_polydata(part)
        if cutaway and part.role != "detector":
            mesh = mesh.clip(normal=(0, 1, 0), origin=(0, 0, 0), invert=True)
            if mesh.n_points == 0:
                continue
        if part.role == "detector":
            pl.add_mesh(mesh, color="#ffd400", show_edges=False)
            legend.append([f"{part.name} (detector)", "#ffd400"])
        elif color_by == "part":
            color = PART_COLORS[i % len(PART_COLORS)]
            pl.add_mesh(mesh, color=color, smooth_shading=True, specular=0.2)
            legend.append([part.name, color])
        else:
            value = absorbed.get(part.name, 0.0)
            mesh.cell_data["log10 absorbed power (W)"] = np.full(mesh.n_cells, np.log10(value) if value > 0 else lo)
            pl.add_mesh(mesh, scalars="log10 absorbed power (W)", cmap="inferno", clim=(lo, hi),
                        show_scalar_bar=not bar_shown, smooth_shading=True,
                        scalar_bar_args={"title": "log10 absorbed (W)", "color": "black", "vertical": True,
                                         "position_x": 0.82, "position_y": 0.25, "width": 0.08, "height": 0.5})
            bar_shown = True
    if ray_paths:
        lines, values, hits = [], [], []
        for pts, wts, reached in ray_paths:
            for k in range(len(wts)):
                lines.append(pts[k:k + 2])
                values.append(np.log10(max(wts[k], 1e-12)))
                hits.append(reached)
        if lines:
            seg = np.concatenate(lines)
            cells = np.hstack([np.full((len(lines), 1), 2), np.arange(2 * len(lines)).reshape(-1, 2)]).ravel()
            poly = pv.PolyData(seg, lines=cells)
            poly.cell_data["log10 relative ray power"] = np.array(values)
            hit = np.array(hits)
            other = poly.extract_cells(np.flatnonzero(~hit)) if (~hit).any() else None
            if other is not None and other.n_cells:
                pl.add_mesh(other, scalars="log10 relative ray power", cmap="viridis", line_width=1.5,
                            opacity=0.8, clim=(min(values), 0.0),
                            scalar_bar_args={"title": "log10 relative ray power", "color": "black",
                                             "position_x": 0.05, "vertical": True})
            if hit.any():
                pl.add_mesh(poly.extract_cells(np.flatnonzero(hit)), color="red", line_width=3.0)
                legend.append(["rays reaching the detector", "red"])
    legend_shown = bool(legend and color_by == "part")
    if legend_shown:  # in the right-hand strip that the camera below leaves free of the scene
        pl.add_legend(legend, bcolor="white", face="rectangle", loc="upper right",
                      size=(LEGEND_WIDTH, min(0.035 * len(legend), 0.5)))
    if title:
        import textwrap

        width = max(40, int(window_size[0] / 14))  # characters that fit at font size 10
        pl.add_text("\n".join(textwrap.wrap(title, width)), font_size=10, color="black", position="upper_edge")
    if camera is None:
        # look into the cut (the kept half is y < 0) from +y, a little above and to the side
        lo, hi = scene.bounds_mm
        center = 0.5 * (lo + hi)
        dist = 3.0 * float(np.max(hi - lo))
        view = np.array([0.35, 1.0, 0.3])
        pl.camera_position = [tuple(center + dist * view / np.linalg.norm(view)), tuple(center), (0.0, 0.0, 1.0)]
        pl.enable_parallel_projection()
        pl.reset_camera()
        if legend_shown:
            _leave_room_right(pl, LEGEND_WIDTH, window_size)
    else:
        pl.camera_position = camera
    if off_screen:
        out = Path(path) if path is not None else Path("scene.png")
        image = pl.screenshot(return_img=True)
        pl.close()
        import io

        from PIL import Image

        buf = io.BytesIO()
        Image.fromarray(image).save(buf, format=out.suffix.lstrip(".").upper().replace("JPG", "JPEG") or "PNG")
        atomicio.write_bytes(out, buf.getvalue())  # a reader never sees half a picture
        return out
    pl.show()
    return None


def plot_detector_map(imap, path=None, title: str = "Detector irradiance", ax=None, rebin: int = 1):
    """Irradiance map of one detector (``TraceResult.maps[name]``), log colour scale, mm axes.

    rebin : sum blocks of rebin x rebin bins first (fewer, less noisy bins; must divide the bin counts)
    """
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    power = np.asarray(imap.power_w, dtype=float)
    eu, ev = np.asarray(imap.edges_u_mm), np.asarray(imap.edges_v_mm)
    if rebin > 1:
        nu, nv = power.shape
        if nu % rebin or nv % rebin:
            raise ValueError(f"rebin {rebin} does not divide the map's {nu} x {nv} bins")
        power = power.reshape(nu // rebin, rebin, nv // rebin, rebin).sum(axis=(1, 3))
        eu, ev = eu[::rebin], ev[::rebin]
    e = power / np.outer(np.diff(eu), np.diff(ev))
    own = ax is None
    if own:
        fig, ax = plt.subplots(figsize=(6, 5), dpi=120)
    pos = e[e > 0]
    if len(pos):
        # at most 4 decades below the peak, so a few low-weight bins do not wash out the map
        vmin = max(pos.min(), pos.max() * 1e-4)
        im = ax.pcolormesh(eu, ev, np.ma.masked_less_equal(e.T, 0), norm=LogNorm(vmin=vmin, vmax=pos.max()),
                           cmap="inferno", shading="flat")
        ax.figure.colorbar(im, ax=ax, label="irradiance (W/mm^2)")
    else:
        ax.text(0.5, 0.5, "no power detected", transform=ax.transAxes, ha="center")
    ax.set_aspect("equal")
    ax.set_xlabel("u (mm)")
    ax.set_ylabel("v (mm)")
    ax.set_title(title, fontsize=10)
    if own:
        fig.tight_layout()
        if path is not None:
            atomicio.write_figure(fig, path)
            plt.close(fig)
    return ax
