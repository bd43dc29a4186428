"""Result tables for other programs: pandas DataFrames, and the study report's tables as CSV.

``data_frame(rows, columns)`` (straylight.frames) is what every result's ``to_pandas()`` calls (pandas
is optional: ``pip install pandas``). ``write_report_tables(out_dir, pst, report, crit, sweep, direct)`` writes
each table of the study's index.html as ``table_<name>.csv``: the same rows, numbers unformatted,
one header row of snake_case names with units (NaN as an empty cell).
"""
from __future__ import annotations

import csv
import math
from pathlib import Path

import atomicio
from straylight.frames import data_frame
from straylight.thermal.tables import THERMAL_TABLE, thermal_rows


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

    def to_json_dict(self) -> dict:
        raise NotImplementedError(f"{type(self).__name__} must define to_json_dict()")

    def csv_table(self) -> tuple[tuple, list[dict]]:
        raise NotImplementedError(f"{type(self).__name__} must define csv_table()")

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


def report_tables(pst, report, crit, sweep=None, direct=()) -> dict:
    """{name: (columns, rows)} for the tables of the study report, in the order it shows them."""
    out: dict[str, tuple[tuple, list[dict]]] = {}
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


__all__ = ["data_frame", "TableRepr", "ResultFiles", "report_tables", "write_csv_table", "write_report_tables",
           "THERMAL_TABLE", "thermal_rows"]
