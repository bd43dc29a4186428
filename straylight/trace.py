"""The entry point of the Monte Carlo engine: :func:`trace` (docs/engine.md).

The engine itself lives in :mod:`straylight.engine`; the names other modules use are re-exported
here, so ``from straylight.trace import trace, TraceOptions`` keeps working.
"""
from __future__ import annotations

import numpy as np

from straylight.distribute import run_distributed
from straylight.engine.core import (  # noqa: F401 - re-exported
    AUTO_BATCH_MAX_RAYS, ROLE_CODES, TALLY_BUDGET_BYTES, Tally, TraceError, TraceOptions, TraceResult, TraceSpec,
    _build_result, _chunk_maps, _COMPILED, _Compiled, _compiled, _NoIsect, auto_batch_rays, make_spec, run_batch,
    run_batch_reference, scene_epsilon)
from straylight.engine.threads import run_local, run_threads, shared_pool  # noqa: F401 - re-exported
from straylight.rng import batches, n_chunks


def trace(scene, sources, n_rays, seed=0, materials=None, options=None, workers=None, client=None,
          scheduler=None, intersector=None, threads=None) -> TraceResult:
    """Trace ``n_rays`` rays from ``sources`` through ``scene``; see docs/engine.md.

    Parameters
    ----------
    scene : geometry.Scene
    sources : a source or a list of sources (straylight.sources)
    n_rays : int
    seed : int, non-negative
    materials : dict name -> Brdf, optional (else ``materials.load_material(name)``)
    options : TraceOptions
    workers, client, scheduler : run on dask (straylight.distribute); default in-process
    intersector : an intersector object to use in-process (e.g. ReferenceIntersector)
    threads : int, optional
        in-process thread pool of this size (embree and the compiled kernels release the GIL;
        materials, sources and bookkeeping do not); same numbers as any other way of running
    """
    if threads is not None and (isinstance(threads, bool) or int(threads) < 1):
        raise TraceError(f"threads must be a positive integer, got {threads!r}")
    spec = make_spec(scene, sources, n_rays, seed, materials, options)
    opt = spec.options
    if opt.first_vertex_sampling and intersector is None and len(spec.detector_parts):
        from dataclasses import replace as _replace

        from straylight.first_vertex import build_table

        spec = _replace(spec, vertex_table=build_table(spec, _compiled(spec)))
    ranges = batches(spec.n_rays, opt.batch_rays or auto_batch_rays(spec.n_rows))
    total_chunks = n_chunks(spec.n_rays)
    if workers is not None or client is not None or scheduler is not None:
        results = run_distributed(spec, ranges, workers=workers, client=client, scheduler=scheduler)
    elif threads is not None and int(threads) > 1:
        results = run_threads(spec, ranges, intersector, int(threads))
    else:
        results = run_local(spec, ranges, intersector)
    cached = _COMPILED.get(spec.token)  # this process's scene, if it traced here; else detectors only
    comp_dets = cached.detectors if cached is not None else _Compiled(spec, intersector=_NoIsect()).detectors
    rows = spec.n_rows
    s1 = np.zeros(rows)
    s2 = np.zeros(rows)
    bins = tuple(int(b) for b in opt.map_bins)
    nb = bins[0] * bins[1]
    D = len(spec.detector_parts)
    map_sums = [(np.zeros(nb), np.zeros(nb)) for _ in range(D)]
    pieces = []
    segments = shadow = 0
    bar = _progress(total_chunks, opt.progress)
    for res in results:  # in chunk order
        for c in range(len(res["s1"])):
            s1 += res["s1"][c]
            s2 += res["s2"][c]
            for j in range(D):
                entry = res["maps"][c][j]
                if entry is not None:
                    map_sums[j][0][entry[0]] += entry[1]
                    map_sums[j][1][entry[0]] += entry[2]
        pieces.append(res["paths"])
        segments += res["segments"]
        shadow += res["shadow_rays"]
        if bar is not None:
            bar.update(len(res["s1"]))
    if bar is not None:
        bar.close()
    return _build_result(spec, comp_dets, s1, s2, map_sums, pieces, segments, shadow)


def _progress(total, enabled):
    if not enabled:
        return None
    import sys

    from tqdm import tqdm

    return tqdm(total=total, unit="chunk", file=sys.stderr, disable=not sys.stderr.isatty())
