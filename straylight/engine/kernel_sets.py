"""The two ways to run the per-vertex work of the walk: :data:`COMPILED` (numba kernels, per-thread
reusable buffers, compiled random streams) and :data:`NUMPY` (their vectorised numpy twins, fresh
arrays, numpy's own Generator). Both give the same bits (tests/straylight/test_engine_kernels.py);
the walk (straylight.engine.walk) and every stage function around the kernels are shared."""
from __future__ import annotations

from typing import Callable, NamedTuple

from straylight.engine.advance import advance, advance_numpy
from straylight.engine.draws import GeneratorDraws
from straylight.engine.hits import hits, hits_numpy
from straylight.engine.interactions.brdf_scatter import frames, frames_numpy, to_world, to_world_numpy
from straylight.engine.interactions.delta_reflection import reflect, reflect_numpy
from straylight.engine.nee import nee_pairs, nee_pairs_numpy, nee_shadow, nee_shadow_numpy, nee_tally, nee_tally_numpy
from straylight.engine.tally_store import DenseTallies, LoggedTallies
from straylight.rng import ChunkStreams


class KernelSet(NamedTuple):
    name: str
    draws: Callable  # (seed, first_chunk, stop_chunk) -> object with fill(rows, width, out, per_chunk)
    reuse_buffers: bool  # per-thread tally log and uniform scratch (straylight.engine.compiled_scene)
    hits: Callable
    frames: Callable
    to_world: Callable
    reflect: Callable
    nee_pairs: Callable
    nee_shadow: Callable
    nee_tally: Callable
    advance: Callable
    tallies: Callable  # (rows, rays of the batch) -> a tally store (straylight.engine.tally_store)


COMPILED = KernelSet("compiled", ChunkStreams, True, hits, frames, to_world, reflect, nee_pairs, nee_shadow, nee_tally,
                     advance, LoggedTallies)
NUMPY = KernelSet("numpy", GeneratorDraws, False, hits_numpy, frames_numpy, to_world_numpy, reflect_numpy,
                  nee_pairs_numpy, nee_shadow_numpy, nee_tally_numpy, advance_numpy, DenseTallies)
