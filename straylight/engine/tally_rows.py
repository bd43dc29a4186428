"""The rows of the per-ray tally matrix (one column per ray of a batch, one row per tally).

Per part (P rows each): ``incident`` (power arriving by the walk), ``first_hit`` (first event on
the part), ``absorbed`` (physical absorption), ``roulette`` (power Russian roulette removed or
added), ``nee_exchange`` (walk hits left to NEE minus NEE contributions made from the part),
``truncated`` (power in flight after max_events). Per detector (D rows each): ``detector_nee``,
``detector_direct`` (walk hits with their MIS share), ``detector_walk`` (all walk hits). Then one
``escaped`` row. The chunk sums add derived rows: ``ledger_absorbed`` (P: absorbed + roulette +
nee_exchange + truncated) and ``detector_total`` (D: nee + direct).
"""
from __future__ import annotations

from typing import NamedTuple


class TallyRows(NamedTuple):
    """First row of each block (a numba-friendly tuple of ints, passed whole to the kernels)."""

    n_parts: int
    n_detectors: int
    incident: int
    first_hit: int
    absorbed: int
    roulette: int
    nee_exchange: int
    truncated: int
    detector_nee: int
    detector_direct: int
    detector_walk: int
    escaped: int
    n_per_ray: int  # rows the walk fills
    ledger_absorbed: int  # derived rows, added by the chunk sums
    detector_total: int
    n_summed: int  # rows of the chunk sums


def tally_rows(n_parts: int, n_detectors: int) -> TallyRows:
    p, d = int(n_parts), int(n_detectors)
    escaped = 6 * p + 3 * d
    n = escaped + 1
    return TallyRows(n_parts=p, n_detectors=d, incident=0, first_hit=p, absorbed=2 * p, roulette=3 * p,
                     nee_exchange=4 * p, truncated=5 * p, detector_nee=6 * p, detector_direct=6 * p + d,
                     detector_walk=6 * p + 2 * d, escaped=escaped, n_per_ray=n, ledger_absorbed=n,
                     detector_total=n + p, n_summed=n + p + d)
