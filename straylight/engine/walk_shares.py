"""The random walk's side of a vertex-sampling MIS: a walk hit on a detector that another strategy
also makes keeps only its balance-heuristic share (straylight.engine.first_vertex.FirstVertexWeights,
straylight.engine.second_vertex.SecondVertexShares; docs/engine.md)."""
from __future__ import annotations


def keep_walk_share(event, rec, rec_w, sel, share):
    """The walk hits ``rec[sel]`` (rows of the event) on a detector keep ``share`` of their weights
    ``rec_w[sel]``; the rest moves from the detector's ``detector_direct`` row to the NEE-exchange row
    of the part each ray last left, so the ledger stays exact. Returns the hits still counted (``rec``
    without those left at zero) and their weights."""
    rays = event.rays
    i = rec[sel]
    r = rays.ray[i]
    moved = rec_w[sel] * (1.0 - share)
    tallies, rows = event.tallies, event.rows
    tallies.subtract(rows.detector_direct + event.scene.arrays.detector_of_part[event.hits.part[i]], r, moved)
    tallies.add(rows.nee_exchange + rays.last_part[i], r, moved)
    rec_w = rec_w.copy()
    rec_w[sel] -= moved
    keep = rec_w > 0
    return rec[keep], rec_w[keep]
