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


PST_TABLE = ("off_axis_deg", "azimuth_deg", "pst", "pst_stderr", "rel_error", "vov", "entrance_ratio",
             "entrance_ratio_stderr", "geometric_direct_entrance_ratio", "rays", "stop_reason", "seconds", "flags")
PATHS_TABLE = ("rank", "path", "ancestry", "fraction", "fraction_stderr", "power_w", "stderr_w", "n_records")
ANCESTRY_TABLE = ("ancestry", "fraction", "fraction_stderr", "power_w", "stderr_w")
CRITICAL_TABLE = ("rank", "part", "illuminated", "illuminated_stderr", "view_factor", "view_factor_stderr", "score",
                  "score_stderr", "illuminated_any", "seen_any")


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
            w.writerow(["" if v is None or (isinstance(v, float) and v != v) else v for v in (r.get(c) for c in columns)])
    return path


def write_report_tables(out_dir, pst, report, crit, sweep=None, direct=()) -> dict:
    """Write ``table_<name>.csv`` for each table of the report; returns {name: file name}."""
    out = Path(out_dir)
    names = {}
    for name, (cols, rows) in report_tables(pst, report, crit, sweep, direct).items():
        names[name] = write_csv_table(out / f"table_{name}.csv", cols, rows).name
    return names
