"""The heaviest ray of a point whose error bar cannot be trusted: what path holds its variance.

A point flagged ``unreliable_error`` (VOV > 0.1) or stopped by a cap before its target is held by a
few rare, heavy rays: one ray of "source -> lens_front -> lens_back -> lens_cell -> sensor" held 97 % of
the variance of the guide scope's 15 deg point. The flag says *that*; a user also needs *what*, to know
which part to blacken or which estimator set draws that path (``--estimators lens`` draws scatter points
lit through a lens: docs/engine.md, "Scatter points lit through a lens"; ``--estimators ghosts`` joins points the
beam lights to the sensor through a lens's two-reflection ghost: "Ghost connections").

Chunks are reproducible: chunk c of a trace draws from the streams of (seed, c) whatever else was
traced (CONTRACTS 1: the same numbers for any batch split). So the chunk with the largest share of the
variance is traced again alone, with path records, and its sum is checked against the run's own chunk
sum (to 1e-6 of its size; no report when it differs). That chunk's heaviest ray (the largest (x - mean)^2:
with a heavy tail, the ray behind the flag) is named by the path family (``straylight paths --group-by
family``) that carried most of its power, with its share of the whole run's variance.

Cost: one chunk (1000 rays) with path records, the run's sampling tables reused (kept in this process,
straylight.engine.runtime), only for points whose error bar is flagged.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from straylight.rng import CHUNK_RAYS

#: path events recorded in the retraced chunk (the heavy paths behind a lens are long: a ray trapped by
#: total internal reflection met 11 interfaces)
PATH_DEPTH = 16
#: the retraced chunk's sum must match the run's to this fraction of its scale
MATCH_TOL = 1e-6
LENS_HINT = ("its first scatter point is lit through a lens: `--estimators lens` draws such points directly "
             "(docs/engine.md, \"Scatter points lit through a lens\")")
GHOST_HINT = ("its first scatter point is lit straight and seen through a lens's two-reflection ghost: `--estimators "
              "ghosts` joins such points to the sensor through the ghost (docs/engine.md, \"Ghost connections\")")


def chunk_spread(s1: np.ndarray, s2: np.ndarray, n_rays: int) -> np.ndarray:
    """Per chunk, the sum of (x - mean)^2 over its rays (straylight.stop_rule.reliability's c)."""
    s1 = np.asarray(s1, dtype=np.float64)
    s2 = np.asarray(s2, dtype=np.float64)
    k = len(s1)
    c_n = np.full(k, float(CHUNK_RAYS))
    if k:
        c_n[-1] = n_rays - CHUNK_RAYS * (k - 1)
    mean = float(s1.sum()) / n_rays
    return s2 - 2.0 * mean * s1 + c_n * mean * mean


def untrusted(diagnostics: dict, rel_error: float) -> bool:
    """The point's error bar is flagged (VOV above 0.1, or a cap stopped it before its target) and is not
    negligible (straylight.analyses.types.point_flags' rule)."""
    from straylight.analyses.types import DEFAULT_VOV_LIMIT, NEGLIGIBLE_REL_ERROR

    vov = diagnostics.get("vov")
    heavy = vov is not None and math.isfinite(vov) and vov > DEFAULT_VOV_LIMIT
    capped = diagnostics.get("stop_reason") not in (None, "", "target")
    return (heavy or capped) and math.isfinite(rel_error) and rel_error > NEGLIGIBLE_REL_ERROR


def heaviest_path(job, seed: int, result) -> dict | None:
    """The heaviest ray of ``result`` (a trace of ``job``, straylight.analyses.grid.TraceJob, with
    ``seed``) on ``job.detector``: ``{"family", "variance_share", "ray", "contribution_w", "hint"}``
    (``variance_share``: the ray's (x - mean)^2 over the run's sum of them; ``hint``: a sentence or
    None); None when nothing was detected or the chunk's retrace does not reproduce its sum."""
    from straylight.execution import Execution
    from straylight.trace import trace

    s1, s2 = result.chunks_of(job.detector)
    n = int(result.n_rays)
    spread = chunk_spread(s1, s2, n)
    total = float(spread.sum())
    if len(spread) == 0 or not total > 0 or not math.isfinite(total):
        return None
    c = int(np.argmax(spread))
    n_c = min(CHUNK_RAYS, n - c * CHUNK_RAYS)
    out = job.options.output
    opts = replace(job.options, output=replace(out, record_paths=True, path_depth=max(int(out.path_depth), PATH_DEPTH)))
    again = trace(job.scene, job.sources, n_c, seed, materials=job.materials, options=opts,
                  execution=Execution(first_chunk=c))
    scale = n_c / n  # a ray of the retrace carries n / n_c times its share of the run
    redone = float(again.detectors[job.detector].power_w) * scale
    if abs(redone - float(s1[c])) > MATCH_TOL * (abs(float(s1[c])) + math.sqrt(max(float(s2[c]), 0.0))):
        return None
    paths = again.paths
    if paths is None or len(paths) == 0:
        return None
    det = list(paths.part_names).index(job.detector) if job.detector in paths.part_names else -1
    sel = np.flatnonzero(np.asarray(paths.detector) == det)
    if len(sel) == 0:
        return None
    ray = np.asarray(paths.ray)[sel]
    power = np.asarray(paths.power_w)[sel] * scale
    ids, inv = np.unique(ray, return_inverse=True)
    x = np.bincount(inv, weights=power)
    mean = float(np.sum(s1)) / n
    top = int(np.argmax((x - mean) ** 2))
    power_of: dict = {}  # family label -> the ray's power along it, W
    events_of: dict = {}  # family label -> one record's events
    for row in sel[inv == top]:
        events = paths.describe(int(row))
        label = _family_label(events, job.detector, len(events) >= paths.events.shape[1])
        power_of[label] = power_of.get(label, 0.0) + float(paths.power_w[row]) * scale
        events_of.setdefault(label, events)
    label = max(power_of, key=lambda k: abs(power_of[k]))
    events = events_of[label]
    share = (float(x[top]) - mean) ** 2 / total
    est = job.options.estimator
    hint = LENS_HINT if _lit_through_glass(job, events) and not est.lens_vertex else \
        GHOST_HINT if _seen_through_a_ghost(job, events) and int(est.specular_nee) < 4 else None
    return {"family": label, "variance_share": float(min(share, 1.0)), "ray": int(c * CHUNK_RAYS + ids[top]),
            "contribution_w": float(x[top]), "hint": hint}


def _family_label(events, detector: str, truncated: bool) -> str:
    """The family label of an event sequence, as ``paths --group-by family`` writes it."""
    from straylight.paths import family_events, sequence_label

    return sequence_label(family_events(events), detector, truncated)


def _material(job, name: str):
    """The material ``name`` as the trace had it (the job's dict, else the library's), None if unknown."""
    if job.materials is not None and name in job.materials:
        return job.materials[name]
    from materials import load_material

    try:
        return load_material(name)
    except (KeyError, ValueError, OSError):
        return None


def _lit_through_glass(job, events) -> bool:
    """The path's first scatter point was reached through refracting interfaces only (a lens, a window)."""
    from materials.flags import ComponentFlags, flags_of

    first = next((i for i, (_, kind) in enumerate(events) if kind == "scatter"), None)
    if not first:  # no scatter, or the first event scatters (lit straight)
        return False
    for part, kind in events[:first]:
        material = _material(job, job.scene.part(part).material)
        if kind != "specular" or material is None or not flags_of(material) & ComponentFlags.DELTA_TRANSMISSION:
            return False
    return True


def _transmits(job, part: str) -> bool:
    """Whether the part's material refracts (a lens face, a window)."""
    from materials.flags import ComponentFlags, flags_of

    material = _material(job, job.scene.part(part).material)
    return material is not None and bool(flags_of(material) & ComponentFlags.DELTA_TRANSMISSION)


def _seen_through_a_ghost(job, events) -> bool:
    """The path is "P (scatter, lit straight) -> a -> b -> a -> b -> detector" through two refracting faces a and b:
    the two-reflection ghost of a singlet the ghost connections make (straylight.engine.specular_nee)."""
    if len(events) != 5 or events[0][1] != "scatter" or any(kind != "specular" for _, kind in events[1:]):
        return False
    a, b = events[1][0], events[2][0]
    return a != b and (events[3][0], events[4][0]) == (a, b) and _transmits(job, a) and _transmits(job, b)
