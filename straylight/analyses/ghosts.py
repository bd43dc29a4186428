"""Ghost analysis: detector power grouped by specular / refraction sequence.

A path whose events are all specular (mirror reflections, Fresnel reflections and refractions of
``optical_surface`` parts) is a *specular path*. The most powerful one at the detector is the
*nominal* path (the instrument's design path); every other specular path is a *ghost*. A
two-bounce ghost of the surface pair (A, B) leaves the nominal sequence n at surface n[i] = B by a
reflection, runs back through n[i-1] .. n[k+1] to n[k] = A, reflects there and then follows the
nominal path again: ``n[:i+1] + reversed(n[k:i]) + n[k+1:]`` (the two-bounce ghosts of each
surface pair, as OpticStudio's ghost analysis lists them; FRED calls the sequence the specular
ancestry). Other specular paths are higher-order ghosts. Paths with a BRDF scatter are not ghosts.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import atomicio


def specular_sequence(events):
    """The parts of a path whose events are all specular (a tuple; () for a direct path), else None."""
    if any(kind != "specular" for _, kind in events):
        return None
    return tuple(part for part, _ in events)


def two_bounce_pair(seq, nominal):
    """(A, B): the surfaces of a two-bounce ghost of ``nominal`` (B reflects first, A second), or None."""
    n = list(nominal)
    s = list(seq)
    for i in range(len(n)):
        for k in range(i):
            if s == n[: i + 1] + n[k:i][::-1] + n[k + 1:]:
                return n[k], n[i]
    return None


@dataclass(frozen=True)
class GhostRow:
    rank: int
    kind: str  # "nominal", "two-bounce ghost", "higher-order ghost", "direct"
    sequence: str
    surfaces: str
    power_w: float
    stderr_w: float
    fraction: float  # of the detector total
    n_records: int


@dataclass(frozen=True, eq=False)
class GhostTable:
    detector: str
    total_w: float
    rows: list

    @property
    def ghost_w(self) -> float:
        return float(sum(r.power_w for r in self.rows if "ghost" in r.kind))

    @property
    def ghost_stderr_w(self) -> float:
        # groups are disjoint sets of records; per-ray covariances between them are ignored (upper bound
        # when contributions are positive)
        return float(math.sqrt(sum(r.stderr_w**2 for r in self.rows if "ghost" in r.kind)))

    def to_json_dict(self) -> dict:
        return {"detector": self.detector, "total_w": self.total_w, "ghost_w": self.ghost_w,
                "ghost_stderr_w": self.ghost_stderr_w, "rows": [r.__dict__ for r in self.rows]}

    def markdown(self, top: int = 20) -> str:
        lines = [f"Ghosts at {self.detector} (specular paths; ghost total {self.ghost_w:.3e} W "
                 f"+- {self.ghost_stderr_w:.1e})", "",
                 "| rank | kind | surfaces | sequence | fraction | power (W) | stderr (W) |",
                 "|---|---|---|---|---|---|---|"]
        for r in self.rows[:top]:
            lines.append(f"| {r.rank} | {r.kind} | {r.surfaces} | {r.sequence} | {r.fraction:.3e} | "
                         f"{r.power_w:.3e} | {r.stderr_w:.1e} |")
        return "\n".join(lines) + "\n"

    def write(self, directory) -> None:
        from pathlib import Path

        d = Path(directory)
        atomicio.write_text(d / "ghosts.md", self.markdown())
        atomicio.write_json(d / "ghosts.json", self.to_json_dict())


def ghost_table(paths, detector: str, total_w: float | None = None, nominal=None) -> GhostTable:
    """Ranked specular paths at ``detector`` from path records (``OutputOptions(record_paths=True)``).

    nominal : the design sequence (tuple of part names); default: the most powerful specular path
    """
    groups = [g for g in (paths.group(by=lambda ev, det: specular_sequence(ev) if det == detector else None)
                          if len(paths) else []) if g.key is not None]
    if total_w is None:
        total_w = float(sum(g.power_w for g in paths.group())) if len(paths) else 0.0
    groups.sort(key=lambda g: -g.power_w)
    if nominal is None:
        nominal = next((g.key for g in groups if g.key), ())
    rows = []
    for rank, g in enumerate(groups, start=1):
        seq = g.key
        if seq == ():
            kind, surfaces = "direct", ""
        elif tuple(seq) == tuple(nominal):
            kind, surfaces = "nominal", ""
        else:
            pair = two_bounce_pair(seq, nominal)
            kind = "two-bounce ghost" if pair else "higher-order ghost"
            surfaces = f"{pair[1]} then {pair[0]}" if pair else ""
        label = " -> ".join(["source", *seq, detector])
        frac = g.power_w / total_w if total_w > 0 else math.nan
        rows.append(GhostRow(rank, kind, label, surfaces, g.power_w, g.stderr_w, frac, g.n_records))
    return GhostTable(detector, float(total_w), rows)
