"""Columnar path records of detector contributions, and grouping with standard errors.

Every contribution to a detector (a next-event-estimation shadow ray or a random-walk hit)
is one record: the ray id, the detector part, the power, the number of events before the
detector, a 64-bit key hashing the whole event sequence and the detector, and the first
``path_depth`` events as codes ``part_index * 4 + kind`` (kind 1 = BRDF scatter, 2 = specular, 3 = edge diffraction),
padded with -1.

Standard errors: a group's estimate is ``S1 = sum of its records' power``; each ray's total
contribution to the group is x_r, and ``stderr = sqrt(N/(N-1) (sum x_r^2 - S1^2/N))`` over all
N traced rays (rays without a record have x_r = 0).
"""
from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

KIND_SCATTER = 1
KIND_SPECULAR = 2
KIND_DETECTOR = 3
# A detector event ends a path and is mixed into its key only, never stored among its events, so the
# same kind marks a diffraction in the stored events (a detector part never diffracts).
KIND_DIFFRACTION = 3
KIND_NAMES = {KIND_SCATTER: "scatter", KIND_SPECULAR: "specular", KIND_DIFFRACTION: "diffraction"}
# The path report's ancestry classes and groupings (straylight.analyses.paths_report); here, light to
# import, for the command line's choices.
ANCESTRY = ("direct", "specular_only", "scattered_once", "scattered_more", "diffracted")
GROUP_BY = ("sequence", "family", "first_part", "last_part", "ancestry")

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)


def mix_key(h: np.ndarray, code) -> np.ndarray:
    """Fold one event code into path hashes (splitmix64 finaliser of h ^ (code+1) * golden)."""
    with np.errstate(over="ignore"):
        x = (h ^ (np.asarray(code).astype(np.uint64) + np.uint64(1))) * _GOLDEN
        x = (x ^ (x >> np.uint64(30))) * _M1
        x = (x ^ (x >> np.uint64(27))) * _M2
        return x ^ (x >> np.uint64(31))


def stderr_from_sums(s1, s2, n):
    """Standard error of a sum over n i.i.d. per-ray contributions with sums s1, s2."""
    s1 = np.asarray(s1, dtype=np.float64)
    s2 = np.asarray(s2, dtype=np.float64)
    if n < 2:
        return np.zeros_like(s1)
    var = (s2 - s1 * s1 / n) * (n / (n - 1.0))
    return np.sqrt(np.maximum(var, 0.0))


@dataclass(frozen=True)
class PathGroup:
    """One group of detector contributions."""

    key: object
    detector: str
    events: tuple
    power_w: float
    stderr_w: float
    n_records: int


class AliasDict(dict):
    """A dict keyed by part names that also answers to a part's aliases (``result.detectors["scope/lens:1"]``
    is ``result.detectors["scope/lens"]``, CONTRACTS 6.2); iteration, length and JSON are the dict's own."""

    def __init__(self, data, aliases=()):
        super().__init__(data)
        self.aliases = dict(aliases)

    def __missing__(self, key):
        name = self.aliases.get(key)
        if name is None or not dict.__contains__(self, name):
            raise KeyError(key)
        return self[name]

    def __contains__(self, key):
        return dict.__contains__(self, key) or dict.__contains__(self, self.aliases.get(key, object()))

    def get(self, key, default=None):
        return self[key] if key in self else default

    def __reduce__(self):
        return (AliasDict, (dict(self), tuple(self.aliases.items())))


@dataclass(frozen=True, eq=False)
class PathRecords:
    """Columnar records (see module docstring). ``n_rays``: rays traced (the stderr denominator)."""

    ray: np.ndarray
    detector: np.ndarray
    power_w: np.ndarray
    depth: np.ndarray
    key: np.ndarray
    events: np.ndarray
    part_names: tuple
    n_rays: int
    aliases: tuple = ()  # ((other name, part name), ...): a CAD solid's instance name (CONTRACTS 6.2)

    def __len__(self) -> int:
        return len(self.ray)

    def resolve(self, name: str) -> str:
        """The part name ``name`` means in these records: a part's own name, or an alias only one part has."""
        if name in self.part_names:
            return name
        hits = sorted({part for alias, part in self.aliases if alias == name})
        if len(hits) == 1:
            return hits[0]
        if hits:
            raise ValueError(f"{name!r} names {len(hits)} parts ({', '.join(hits)}); use one of these names")
        return name  # unknown: the caller says what the records hold

    @classmethod
    def concatenate(cls, pieces, part_names, n_rays, path_depth):
        pieces = [p for p in pieces if p is not None and len(p["ray"])]
        if not pieces:
            return cls(
                np.zeros(0, np.int64), np.zeros(0, np.int16), np.zeros(0), np.zeros(0, np.int16),
                np.zeros(0, np.uint64), np.zeros((0, path_depth), np.int16), tuple(part_names), int(n_rays),
            )
        cat = {k: np.concatenate([p[k] for p in pieces]) for k in ("ray", "detector", "power_w", "depth", "key", "events")}
        return cls(cat["ray"], cat["detector"], cat["power_w"], cat["depth"], cat["key"], cat["events"],
                   tuple(part_names), int(n_rays))

    def describe(self, row: int) -> tuple:
        """Event sequence of record ``row`` as ((part name, kind name), ...) (first path_depth events)."""
        out = []
        for code in self.events[row]:
            if code < 0:
                break
            out.append((self.part_names[code // 4], KIND_NAMES.get(int(code % 4), "?")))
        return tuple(out)

    def group(self, by=None) -> list[PathGroup]:
        """Group contributions; returns groups sorted by decreasing power.

        by : None groups by the exact event sequence and detector (the 64-bit key); a callable
        ``by(described_events, detector_name) -> hashable`` gives coarser groups (for example
        ``lambda ev, det: ev[-1][0]``: the last part before the detector).
        """
        if len(self) == 0:
            return []
        if by is None:
            labels, first, inverse = np.unique(self.key, return_index=True, return_inverse=True)
            names = [self.key[i] for i in first]
            reps = first
        else:
            # describe each distinct key once, then map keys to user labels
            ukeys, first, kinv = np.unique(self.key, return_index=True, return_inverse=True)
            user = [by(self.describe(i), self.part_names[self.detector[i]]) for i in first]
            lab_of_key = {}
            names = []
            for lab in user:
                if lab not in lab_of_key:
                    lab_of_key[lab] = len(names)
                    names.append(lab)
            key_to_group = np.array([lab_of_key[lab] for lab in user], dtype=np.int64)
            inverse = key_to_group[kinv]
            reps = np.array([first[np.flatnonzero(key_to_group == g)[0]] for g in range(len(names))])
        inverse = np.asarray(inverse).ravel()
        n_groups = len(names)
        s1 = np.bincount(inverse, weights=self.power_w, minlength=n_groups)
        # per-ray totals within each group (a ray may contribute several records to a coarse group)
        pair = inverse.astype(np.int64) * (int(self.ray.max()) + 1) + self.ray
        upair, pinv = np.unique(pair, return_inverse=True)
        xr = np.bincount(pinv.ravel(), weights=self.power_w)
        s2 = np.bincount(upair // (int(self.ray.max()) + 1), weights=xr * xr, minlength=n_groups)
        err = stderr_from_sums(s1, s2, self.n_rays)
        counts = np.bincount(inverse, minlength=n_groups)
        groups = [
            PathGroup(
                key=names[g],
                detector=self.part_names[self.detector[reps[g]]],
                events=self.describe(reps[g]) if by is None else (),
                power_w=float(s1[g]),
                stderr_w=float(err[g]),
                n_records=int(counts[g]),
            )
            for g in range(n_groups)
        ]
        return sorted(groups, key=lambda grp: -grp.power_w)


def part_family(part: str) -> str:
    """A part's family: its name without a trailing ``_<number>`` (``vane_12`` -> ``vane``)."""
    return re.sub(r"_\d+$", "", part)


def family_events(events) -> tuple:
    """An event sequence ((part, kind), ...) with each part named by its family (``paths --group-by family``)."""
    return tuple((part_family(part), kind) for part, kind in events)


def sequence_label(events, detector: str, truncated: bool = False) -> str:
    """'source -> wall -> vane_7 (specular) -> diffracted at vane_1 -> detector', with runs of one
    event collapsed ('wall x3')."""
    steps: list[list] = []  # [name, count] of each run of one event
    for part, kind in events:
        name = part if kind == "scatter" else f"diffracted at {part}" if kind == "diffraction" else f"{part} ({kind})"
        if steps and steps[-1][0] == name:
            steps[-1][1] += 1
        else:
            steps.append([name, 1])
    middle = [n if k == 1 else f"{n} x{k}" for n, k in steps]
    if truncated:
        middle.append("...")
    return " -> ".join(["source", *middle, detector])
