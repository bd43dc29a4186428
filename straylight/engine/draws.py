"""Random numbers: every ray of chunk k draws from the stream ``chunk_rng(seed, k)``: 5 uniforms
at emission, then :class:`EventColumns` uniforms per event while it lives (ray ids ascending), so
the numbers do not depend on how chunks are grouped into batches, threads or workers.

The compiled walk fills them from :class:`straylight.rng.ChunkStreams` (PCG64 in numba); the numpy
reference walk from numpy's own ``Generator`` (:class:`GeneratorDraws`): the same numbers."""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from straylight.rng import CHUNK_RAYS, chunk_rng

EMISSION_COLUMNS = 5  # source choice, then 4 for the source's emit()


class EventColumns(NamedTuple):
    """Columns of one event's uniforms per ray."""

    sample: int  # 3: the material's direction sample
    roulette: int  # 1: Russian roulette
    nee: int  # 3 per (detector, NEE sample): detector point
    target: int  # 4 with target parts: strategy choice and target point
    width: int
    second: int = 0  # 3 + 3 per detector with second-vertex sampling: critical point, detector points
    second_lobe: int = 0  # 3 more with vertex_lobe_sampling: the lobe draw at the critical point
    #: (strategy name, first column) of the columns the strategies declare (Strategy.uniform_columns),
    #: after all the above, in registry order
    strategies: tuple = ()

    def of(self, strategy: str) -> int:
        """The first of the columns ``strategy`` declared."""
        return dict(self.strategies)[strategy]


def event_columns(n_detectors: int, nee_samples: int, has_target: bool, second_vertex: bool = False,
                  second_lobe: bool = False, strategies=()) -> EventColumns:
    """The layout; ``strategies``: (name, number of columns) each further strategy draws per event."""
    nee_end = 4 + 3 * int(n_detectors) * int(nee_samples)
    target_end = nee_end + (4 if has_target else 0)
    second_end = target_end + (3 + 3 * int(n_detectors) if second_vertex else 0)
    lobe = bool(second_vertex and second_lobe)
    width = second_end + (3 if lobe else 0)
    extra = []
    for name, count in strategies:
        extra.append((name, width))
        width += int(count)
    return EventColumns(sample=0, roulette=3, nee=4, target=nee_end, second=target_end,
                        width=width, second_lobe=second_end if lobe else 0, strategies=tuple(extra))


class GeneratorDraws:
    """The streams of chunks ``first_chunk .. stop_chunk-1`` as numpy Generators, with the ``fill``
    of :class:`straylight.rng.ChunkStreams` (the reference the compiled streams are tested against)."""

    def __init__(self, seed: int, first_chunk: int, stop_chunk: int):
        self.gens = [chunk_rng(seed, k) for k in range(first_chunk, stop_chunk)]

    def fill(self, rows, width, out, per_chunk=1):
        counts = np.bincount(np.asarray(rows) // per_chunk, minlength=len(self.gens))
        out[:] = np.concatenate([self.gens[c].random((counts[c], width)) for c in range(len(self.gens))
                                 if counts[c]] or [np.zeros((0, width))])
        return out


def event_uniforms(draws, ray, width, buf=None):
    """This event's uniforms of the live rays ``ray`` (ascending): chunk k draws (live rays in k,
    width) from its stream, written in place into ``buf`` (flat float64 scratch of at least
    len(ray) * width) when given."""
    m = len(ray)
    U = np.empty((m, width)) if buf is None else buf[:m * width].reshape(m, width)
    return draws.fill(ray, width, U, CHUNK_RAYS)
