"""The self-emission budget as a table and plots: rows of a thermal.json document (CONTRACTS §7.1),
its DataFrame, bars by emitting part, and the distribution-factor matrix."""
from __future__ import annotations

import math

from straylight.frames import data_frame, finish_axes, own_axes

THERMAL_TABLE = ("detector", "part", "power_w", "stderr_w", "fraction", "detector_power_w", "irradiance_w_m2")


def thermal_rows(doc: dict) -> list[dict]:
    """Rows (detector, emitting part), largest first, of a thermal.json document (CONTRACTS §7.1)."""
    rows = []
    for name, d in doc["detectors"].items():
        total = d["power_w"]
        for part, t in sorted(d["by_part"].items(), key=lambda kv: -kv[1]["power_w"]):
            rows.append({"detector": name, "part": part, "power_w": t["power_w"], "stderr_w": t["stderr_w"],
                         "fraction": t["power_w"] / total if total > 0 else math.nan,
                         "detector_power_w": total, "irradiance_w_m2": d["irradiance_w_m2"]})
    return rows


def thermal_frame(res):
    """A :class:`~straylight.thermal.run.ThermalResult` as a DataFrame of :func:`thermal_rows`."""
    return data_frame(thermal_rows(res.to_json_dict()), THERMAL_TABLE)


def plot_thermal(res, path=None, ax=None):
    """Horizontal bars: band power from each emitting part on each detector, 1-sigma bars, log scale."""
    bars = [(f"{p} -> {name}", t.power_w, t.stderr_w) for name, d in res.detectors.items()
            for p, t in sorted(d.by_part.items(), key=lambda kv: -kv[1].power_w) if t.power_w > 0]
    ax, own = own_axes(ax, (8, 0.4 * max(len(bars), 3) + 1.4))
    y = list(range(len(bars)))[::-1]
    ax.barh(y, [b[1] for b in bars], xerr=[min(b[2], 0.999 * b[1]) for b in bars], capsize=3, log=True, color="#c44e52")
    ax.set_yticks(y)
    ax.set_yticklabels([b[0] for b in bars], fontsize=8)
    ax.set_xlabel("band power on the detector (W)")
    ax.set_title(f"Self-emission {res.band_um[0]:g}-{res.band_um[1]:g} um by emitting part (1-sigma bars)", fontsize=10)
    ax.grid(True, axis="x", which="both", alpha=0.3)
    return finish_axes(ax, own, path)


def plot_matrix(matrix, names, title, path=None, ax=None):
    """A square matrix between named parts, log colour scale (zeros blank)."""
    import numpy as np
    from matplotlib.colors import LogNorm

    m = np.asarray(matrix, dtype=float)
    ax, own = own_axes(ax, (1.0 + 0.5 * len(names) + 2, 0.5 * len(names) + 2))
    pos = m[m > 0]
    im = ax.imshow(np.ma.masked_less_equal(m, 0), cmap="viridis",
                   norm=LogNorm(vmin=pos.min(), vmax=pos.max()) if len(pos) else None)
    ax.figure.colorbar(im, ax=ax)
    ax.set_xticks(range(len(names)))
    ax.set_xticklabels(names, rotation=60, ha="right", fontsize=8)
    ax.set_yticks(range(len(names)))
    ax.set_yticklabels(names, fontsize=8)
    ax.set_xlabel("absorbed by")
    ax.set_ylabel("emitted by")
    ax.set_title(title, fontsize=10)
    return finish_axes(ax, own, path)
