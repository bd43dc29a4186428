"""Result tables for other programs: pandas DataFrames, and the study report's tables as CSV.

``data_frame(rows, columns)`` is what every result's ``to_pandas()`` calls (pandas is optional:
``pip install pandas``). ``write_report_tables(out_dir, pst, report, crit, sweep, direct)`` writes
each table of the study's index.html as ``table_<name>.csv``: the same rows, numbers unformatted,
one header row of snake_case names with units (NaN as an empty cell).
"""
from __future__ import annotations

import csv
import math
from pathlib import Path

import atomicio


def data_frame(rows: list[dict], columns):
    """A pandas DataFrame of ``rows`` (dicts) with ``columns`` in this order (missing keys: NaN/None)."""
    try:
        import pandas as pd
    except ImportError as exc:  # an optional dependency: say how to get it
        raise ImportError("to_pandas() needs pandas: pip install pandas") from exc
    return pd.DataFrame([{c: r.get(c) for c in columns} for r in rows], columns=list(columns))


class TableRepr:
    """Mixin for results with ``to_pandas()``: a notebook shows them as their table (plain repr without pandas)."""

    def _repr_html_(self):
        try:
            frame = self.to_pandas()
        except ImportError:
            return None
        return frame.to_html(max_rows=30)


class ResultFiles:
    """Mixin for results written as JSON and CSV: ``to_json_dict()`` and ``csv_table()`` ->
    (columns, rows as dicts) are the result's own; the files are written atomically (atomicio), the
    JSON strict (a non-finite number as null, CONTRACTS 1) with no final newline, the CSV with missing cells empty."""

    def write_json(self, path) -> Path:
        path = Path(path)
        atomicio.write_json(path, self.to_json_dict(), final_newline=False)
        return path

    def write_csv(self, path) -> Path:
        path = Path(path)
        columns, rows = self.csv_table()
        with atomicio.atomic_open(path, "w") as fh:
            writer = csv.DictWriter(fh, fieldnames=list(columns), restval="")
            writer.writeheader()
            writer.writerows(rows)
        return path


PST_TABLE = ("off_axis_deg", "azimuth_deg", "pst", "pst_stderr", "rel_error", "vov", "entrance_ratio",
             "entrance_ratio_stderr", "geometric_direct_entrance_ratio", "rays", "stop_reason", "seconds", "flags")
PATHS_TABLE = ("rank", "path", "ancestry", "fraction", "fraction_stderr", "power_w", "stderr_w", "n_records",
               "variance_fraction")
ANCESTRY_TABLE = ("ancestry", "fraction", "fraction_stderr", "power_w", "stderr_w")
CRITICAL_TABLE = ("rank", "part", "illuminated", "illuminated_stderr", "view_factor", "view_factor_stderr", "score",
                  "score_stderr", "illuminated_any", "seen_any")
THERMAL_TABLE = ("detector", "part", "power_w", "stderr_w", "fraction", "detector_power_w", "irradiance_w_m2")


def report_tables(pst, report, crit, sweep=None, direct=()) -> dict:
    """{name: (columns, rows)} for the tables of the study report, in the order it shows them."""
    out = {}
    rows = []
    for i, r in enumerate(pst.flagged_rows()):
        d = float(direct[i]) if i < len(direct) else math.nan
        rows.append({**r, "rel_error": r["pst_stderr"] / r["pst"] if r["pst"] > 0 else math.nan,
                     "geometric_direct_entrance_ratio": d, "stop_reason": r.get("stop_reason", "rays given")})
    out["pst"] = (PST_TABLE, rows)
    out["paths"] = (PATHS_TABLE, [{**r.__dict__, "path": r.label} for r in report.rows])
    tot = report.total_w
    out["ancestry"] = (ANCESTRY_TABLE, [{"ancestry": k, "power_w": v[0], "stderr_w": v[1],
                                         "fraction": v[0] / tot if tot > 0 else math.nan,
                                         "fraction_stderr": v[1] / tot if tot > 0 else math.nan}
                                        for k, v in report.ancestry_w.items()])
    ranked = crit.ranking + [r for r in sorted(crit.rows, key=lambda r: -(r.illuminated + r.view_factor))
                             if r not in crit.ranking]
    out["critical"] = (CRITICAL_TABLE, [{**r.__dict__, "rank": i + 1 if r in crit.ranking else ""}
                                        for i, r in enumerate(ranked)])
    if sweep is not None:
        cols = (sweep.parameter,) + tuple(f"{k}_at_{a:g}_deg" for a in sweep.off_axis_deg for k in ("pst", "pst_stderr"))
        out["sweep"] = (cols, [{sweep.parameter: v, **{f"{k}_at_{a:g}_deg": float(getattr(sweep, k)[i, j])
                                                       for j, a in enumerate(sweep.off_axis_deg)
                                                       for k in ("pst", "pst_stderr")}}
                               for i, v in enumerate(sweep.values)])
    return out


def write_csv_table(path, columns, rows) -> Path:
    """One table as CSV (atomically): a header row, then each row's values; NaN and None as empty cells."""
    path = Path(path)
    with atomicio.atomic_open(path, "w") as fh:
        w = csv.writer(fh)
        w.writerow(columns)
        for r in rows:
            w.writerow(["" if v is None or (isinstance(v, float) and math.isnan(v)) else v for v in (r.get(c) for c in columns)])
    return path


def write_report_tables(out_dir, pst, report, crit, sweep=None, direct=()) -> dict:
    """Write ``table_<name>.csv`` for each table of the report (``thermal`` too when the study wrote
    thermal.json); returns {name: file name}."""
    out = Path(out_dir)
    names = {}
    tables = report_tables(pst, report, crit, sweep, direct)
    if (out / "thermal.json").exists():  # the self-emission budget (straylight.thermal.report)
        import json

        tables["thermal"] = (THERMAL_TABLE, thermal_rows(json.loads((out / "thermal.json").read_text())))
    for name, (cols, rows) in tables.items():
        names[name] = write_csv_table(out / f"table_{name}.csv", cols, rows).name
    return names



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


def _own_axes(ax, size):
    import matplotlib.pyplot as plt

    if ax is not None:
        return ax, False
    return plt.subplots(figsize=size, dpi=120)[1], True


def _finish(ax, own, path):
    import matplotlib.pyplot as plt

    if own:
        ax.figure.tight_layout()
        if path is not None:
            atomicio.write_figure(ax.figure, path)
            plt.close(ax.figure)
    return ax


def plot_thermal(res, path=None, ax=None):
    """Horizontal bars: band power from each emitting part on each detector, 1-sigma bars, log scale."""
    bars = [(f"{p} -> {name}", t.power_w, t.stderr_w) for name, d in res.detectors.items()
            for p, t in sorted(d.by_part.items(), key=lambda kv: -kv[1].power_w) if t.power_w > 0]
    ax, own = _own_axes(ax, (8, 0.4 * max(len(bars), 3) + 1.4))
    y = list(range(len(bars)))[::-1]
    ax.barh(y, [b[1] for b in bars], xerr=[min(b[2], 0.999 * b[1]) for b in bars], capsize=3, log=True, color="#c44e52")
    ax.set_yticks(y)
    ax.set_yticklabels([b[0] for b in bars], fontsize=8)
    ax.set_xlabel("band power on the detector (W)")
    ax.set_title(f"Self-emission {res.band_um[0]:g}-{res.band_um[1]:g} um by emitting part (1-sigma bars)", fontsize=10)
    ax.grid(True, axis="x", which="both", alpha=0.3)
    return _finish(ax, own, path)


def plot_matrix(matrix, names, title, path=None, ax=None):
    """A square matrix between named parts, log colour scale (zeros blank)."""
    import numpy as np
    from matplotlib.colors import LogNorm

    m = np.asarray(matrix, dtype=float)
    ax, own = _own_axes(ax, (1.0 + 0.5 * len(names) + 2, 0.5 * len(names) + 2))
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
    return _finish(ax, own, path)
