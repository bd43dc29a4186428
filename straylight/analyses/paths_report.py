"""Stray-light path report: which sequences of parts and events bring power to the detector.

Every contribution to the detector is recorded by the engine with its event sequence
(``straylight.paths.PathRecords``). Here contributions are grouped (by the exact sequence
of parts and events, by the first or last part, or by ancestry), ranked by power, and
given standard errors computed per ray (a ray may contribute several records to one
group). Ancestry classes:

``direct``          no event between the source and the detector
``specular_only``   only specular reflections (mirror parts or specular lobes)
``scattered_once``  exactly one BRDF scatter
``scattered_more``  two or more BRDF scatters
``diffracted``      bent at a diffracting edge (CONTRACTS §6.5) at least once, whatever else happened

Grouped by first or last part, a group mixes classes (ancestry "mixed"), except "(direct)".

The groups partition the records, so the group powers sum to the detector's total power
(to round-off). Fractions are power / detector total; their errors are the group's
standard error over the total (the total's own error is quoted separately).
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

import atomicio
from straylight.analyses.estimators import estimator_options
from straylight.analyses.pst import detector_name
from straylight.analyses.tables import TableRepr
from straylight.execution import Execution, as_execution
from straylight.paths import ANCESTRY, GROUP_BY, family_events, sequence_label
from straylight.trace import EstimatorOptions, OutputOptions, TraceOptions, trace


def ancestry_of(events) -> str:
    """Ancestry class of an event sequence ((part, "scatter"|"specular"), ...)."""
    n_scatter = sum(1 for _, kind in events if kind == "scatter")
    if not events:
        return "direct"
    if any(kind == "diffraction" for _, kind in events):
        return "diffracted"
    if n_scatter == 0:
        return "specular_only"
    return "scattered_once" if n_scatter == 1 else "scattered_more"


@dataclass(frozen=True)
class PathRow:
    """One ranked group."""

    rank: int
    label: str
    ancestry: str
    power_w: float
    stderr_w: float
    fraction: float
    fraction_stderr: float
    n_records: int
    # share of the detector estimate's variance carried by this group: stderr_w^2 / total_stderr_w^2
    # (the groups' own variances; a ray that contributes to several groups adds covariance terms)
    variance_fraction: float = math.nan


@dataclass(frozen=True, eq=False)
class PathReport(TableRepr):
    """Ranked path groups at one detector.

    rows : every group, by decreasing power (``top`` limits only the table and plot)
    total_w, total_stderr_w : the detector's power from the trace (all records)
    ancestry_w : {class: (power_w, stderr_w)} over all records
    """

    rows: list
    total_w: float
    total_stderr_w: float
    detector: str
    n_rays: int
    group_by: str
    ancestry_filter: tuple
    ancestry_w: dict = field(default_factory=dict)
    title: str = ""
    trace: object = field(default=None, repr=False)  # the TraceResult it came from, when kept (straylight.api)

    @property
    def fraction_sum(self) -> float:
        return float(sum(r.power_w for r in self.rows) / self.total_w) if self.total_w > 0 else math.nan

    def to_json_dict(self, top: int | None = None) -> dict:
        return {"detector": self.detector, "rays": self.n_rays, "group_by": self.group_by,
                "ancestry_filter": list(self.ancestry_filter), "title": self.title,
                "total_w": self.total_w, "total_stderr_w": self.total_stderr_w,
                "ancestry": {k: {"power_w": v[0], "stderr_w": v[1],
                                 "fraction": v[0] / self.total_w if self.total_w > 0 else None}
                             for k, v in self.ancestry_w.items()},
                "n_groups": len(self.rows),
                "groups": [r.__dict__ for r in self.rows[:top]]}

    def to_pandas(self):
        """Every ranked group as a pandas DataFrame (columns of paths.csv; pandas is optional)."""
        from straylight.analyses.tables import PATHS_TABLE, data_frame

        return data_frame([{**r.__dict__, "path": r.label} for r in self.rows], PATHS_TABLE)

    def markdown(self, top: int = 20) -> str:
        head = (f"Detector `{self.detector}`: total {self.total_w:.4e} +- {self.total_stderr_w:.2e} W "
                f"({self.n_rays} rays); groups by {self.group_by.replace('_', ' ')}"
                + (f", ancestry {', '.join(self.ancestry_filter)}" if self.ancestry_filter else "") + "\n\n")
        lines = ["| rank | path | ancestry | fraction | +- | share of the variance | power (W) | records |",
                 "|---:|---|---|---:|---:|---:|---:|---:|"]
        for r in self.rows[:top]:
            var = f"{r.variance_fraction:.1%}" if r.variance_fraction == r.variance_fraction else "-"
            lines.append(f"| {r.rank} | {r.label} | {r.ancestry} | {r.fraction:.3%} | {r.fraction_stderr:.2%} | "
                         f"{var} | {r.power_w:.3e} | {r.n_records} |")
        rest = self.rows[top:]
        if rest:
            p = sum(r.power_w for r in rest)
            lines.append(f"| | {len(rest)} more groups | | {p / self.total_w:.3%} | | | {p:.3e} | "
                         f"{sum(r.n_records for r in rest)} |")
        anc = ["", "| ancestry | fraction | +- |", "|---|---:|---:|"]
        for k, (p, e) in self.ancestry_w.items():
            if self.total_w > 0:
                anc.append(f"| {k} | {p / self.total_w:.3%} | {e / self.total_w:.2%} |")
        return head + "\n".join(lines + anc) + "\n"

    def write_csv(self, path) -> Path:
        path = Path(path)
        with atomicio.atomic_open(path, "w") as fh:
            writer = csv.writer(fh)
            writer.writerow(["rank", "path", "ancestry", "fraction", "fraction_stderr", "power_w", "stderr_w",
                             "n_records", "variance_fraction"])
            for r in self.rows:
                writer.writerow([r.rank, r.label, r.ancestry, r.fraction, r.fraction_stderr, r.power_w,
                                 r.stderr_w, r.n_records, r.variance_fraction])
        return path

    def write_json(self, path, top: int | None = None) -> Path:
        path = Path(path)
        atomicio.write_json(path, self.to_json_dict(top), final_newline=False)
        return path

    def plot(self, path=None, top: int = 15, ax=None):
        """Horizontal bars of the ``top`` groups' power fractions (log scale), 1-sigma error bars."""
        import matplotlib.pyplot as plt

        rows = [r for r in self.rows[:top] if r.fraction > 0]
        own = ax is None
        if own:
            fig, ax = plt.subplots(figsize=(9, 0.38 * max(len(rows), 3) + 1.4), dpi=120)
        colors = {"direct": "#4c72b0", "specular_only": "#8172b2", "scattered_once": "#dd8452", "diffracted": "#937860",
                  "scattered_more": "#c44e52", "mixed": "#8c8c8c"}
        y = np.arange(len(rows))[::-1]
        frac = np.array([r.fraction for r in rows])
        err = np.array([min(r.fraction_stderr, 0.999 * r.fraction) for r in rows])
        ax.barh(y, frac, xerr=err, color=[colors[r.ancestry] for r in rows], capsize=3, log=True)
        ax.set_yticks(y)
        ax.set_yticklabels([_short(r.label) for r in rows], fontsize=7)
        ax.set_xlabel("fraction of detector power")
        shown = [k for k in colors if any(r.ancestry == k for r in rows)]
        handles = [plt.Rectangle((0, 0), 1, 1, color=colors[k]) for k in shown]
        ax.legend(handles, [k.replace("_", " ") for k in shown], fontsize=7, loc="lower right")
        ax.set_title(self.title or f"Stray-light paths to {self.detector} (1-sigma bars)", fontsize=10)
        ax.grid(True, axis="x", which="both", alpha=0.3)
        if own:
            fig.tight_layout()
            if path is not None:
                atomicio.write_figure(fig, path)
                plt.close(fig)
        return ax


def _short(label: str, width: int = 70) -> str:
    label = label.removeprefix("source -> ")
    return label if len(label) <= width else label[: width - 3] + "..."


def path_report(paths, detector: str | None = None, total=None, group_by: str = "sequence",
                ancestry=None, title: str = "") -> PathReport:
    """Group and rank the detector contributions of a traced ``PathRecords``.

    Parameters
    ----------
    paths : straylight.paths.PathRecords (``trace(..., options=TraceOptions(output=OutputOptions(record_paths=True)))``)
    detector : detector part name (default: the only detector in the records)
    total : Tally of the detector from the same trace (power_w, stderr_w); default: the sum of records
    group_by : "sequence" (exact parts and events), "family" (the sequence with numbered parts of one
        family merged: vane_1 .. vane_33 -> vane), "first_part", "last_part" or "ancestry"
    ancestry : None or a list of ANCESTRY classes to keep (the fractions stay relative to the total)
    """
    if group_by not in GROUP_BY:
        raise ValueError(f"group_by must be one of {', '.join(GROUP_BY)}, got {group_by!r}")
    keep = tuple(ancestry or ())
    bad = [a for a in keep if a not in ANCESTRY]
    if bad:
        raise ValueError(f"unknown ancestry {', '.join(bad)}; expected {', '.join(ANCESTRY)}")
    det_index = sorted(set(np.asarray(paths.detector).tolist()))
    names = [paths.part_names[i] for i in det_index]
    if detector is not None and hasattr(paths, "resolve"):
        detector = paths.resolve(detector)  # an instance name answers too (CONTRACTS 6.2)
    if detector is None:
        if len(names) > 1:
            raise ValueError(f"records cover several detectors ({', '.join(names)}); name one")
        detector = names[0] if names else "detector"
    elif names and detector not in names:
        raise ValueError(f"no records for detector {detector!r}; recorded: {', '.join(names)}")
    depth = int(paths.events.shape[1]) if paths.events.ndim == 2 else 0

    def truncated(events):
        return len(events) >= depth > 0

    def key_of(events, det):
        if det != detector:
            return None
        anc = ancestry_of(events)
        if group_by == "ancestry":
            return (anc, anc)
        if group_by in ("first_part", "last_part"):
            if not events:
                return ("(direct)", "direct")
            part = events[0][0] if group_by == "first_part" else events[-1][0]
            return (f"{group_by.split('_')[0]}: {part}", "mixed")
        if group_by == "family":  # vane_1 .. vane_33 -> vane: where a repeated part's light comes from
            events = family_events(events)
        return (sequence_label(events, det, truncated(events)), anc)

    def kept_key(events, det):
        return key_of(events, det) if not keep or ancestry_of(events) in keep else None

    # filtering before grouping: a coarse group then holds only the kept classes
    groups = [g for g in (paths.group(by=kept_key) if len(paths) else []) if g.key is not None]
    tot_w = float(total.power_w) if total is not None else float(sum(g.power_w for g in groups))
    tot_se = float(total.stderr_w) if total is not None else math.nan
    # ancestry totals, always over every record of this detector
    anc_groups = paths.group(by=lambda ev, det: ancestry_of(ev) if det == detector else None) if len(paths) else []
    ancestry_w = {a: (0.0, 0.0) for a in ANCESTRY}
    for g in anc_groups:
        if g.key is not None:
            ancestry_w[g.key] = (g.power_w, g.stderr_w)
    rows = [(g.key[0], g.key[1], g) for g in groups]
    var_tot = tot_se * tot_se
    if not var_tot > 0 and len(paths):  # no trace total given: the variance of all this detector's records
        whole = [g for g in paths.group(by=lambda ev, det: det if det == detector else None) if g.key is not None]
        var_tot = whole[0].stderr_w ** 2 if whole else math.nan
    out = []
    for rank, (label, anc, g) in enumerate(sorted(rows, key=lambda t: -t[2].power_w), start=1):
        frac = g.power_w / tot_w if tot_w > 0 else math.nan
        out.append(PathRow(rank, label, anc, g.power_w, g.stderr_w, frac,
                           g.stderr_w / tot_w if tot_w > 0 else math.nan, g.n_records,
                           g.stderr_w ** 2 / var_tot if var_tot > 0 else math.nan))
    return PathReport(out, tot_w, tot_se, detector, int(paths.n_rays), group_by, keep, ancestry_w, title)


def paths_analysis(setup, off_axis: float, azimuth: float = 0.0, n_rays: int = 100_000, seed: int = 0,
                   nee: bool = True, group_by: str = "sequence", ancestry=None, path_depth: int = 12,
                   execution: Execution | None = None):
    """Trace the setup's beam at one tilt with path recording and return (PathReport, TraceResult).
    ``execution``: where to run (a dask cluster for this trace when it names workers or a scheduler)
    and whether to show progress."""
    det = detector_name(setup.scene, setup.detector)
    # the estimators `pst` traces (the variance split is the one of pst's error bars), or the plain walk
    opts = replace(estimator_options("default", materials=setup.materials) if nee else TraceOptions(estimator=EstimatorOptions(nee=False)),
                   output=OutputOptions(record_paths=True, path_depth=path_depth))
    with as_execution(execution).opened() as ex:
        res = trace(setup.scene, [setup.beam.source(off_axis, azimuth)], n_rays=int(n_rays), seed=seed,
                    materials=setup.materials, options=opts, execution=ex)
    title = f"Stray-light paths at {math.degrees(off_axis):g} deg off axis (1-sigma bars)"
    report = path_report(res.paths, det, res.detectors[det], group_by=group_by, ancestry=ancestry, title=title)
    return report, res
