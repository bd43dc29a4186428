"""The entry point of the Monte Carlo engine: :func:`trace` (docs/engine.md).

Forward Monte Carlo: sources -> surfaces (BRDF scatter / mirror / absorber) -> detectors, with
next-event estimation, Russian roulette and an exact power ledger. The engine is the package
:mod:`straylight.engine`, one file per stage:

    options, spec          what is asked, and what a worker needs (picklable)
    compiled_scene         triangle planes, detector samplers, embree (once per process)
    ray_batch, draws       the live rays as one structure of arrays; the random streams
    emission               sources -> rays
    walk                   event after event: cast, hits, interactions, advance
    hits                   escape, detection, absorption (terminal interactions)
    interactions/          what a continuing hit does: surface_response, delta_reflection (extension point)
    nee, targets           next-event estimation; target-part MIS
    first_vertex           area sampling of single-scatter vertices (MIS with the walk)
    second_vertex          area sampling of the critical surfaces as second vertex (MIS with the walk)
    advance                absorption, roulette, truncation, next ray state
    tallies, results       per-chunk sums, maps, paths; TraceResult
    scheduling             batches in process, on threads, or on dask (straylight.engine.backends.dask)

The names other modules use are importable from here.
"""
from __future__ import annotations

import warnings
from dataclasses import replace
from typing import Any

from straylight.engine.compiled_scene import detector_samplers
from straylight.engine.plan import build_tables, resolve as resolve_plan, without_declined, without_missing_tables
from straylight.engine.strategies.base import TableTools
from straylight.engine.strategies import registry
from straylight.engine.options import (  # noqa: F401 - re-exported
    EstimatorOptions,
    OutputOptions,
    PhysicsOptions,
    TraceError,
    TraceOptions,
)
from straylight.engine.results import BatchTotals, Tally, TraceResult  # noqa: F401 - re-exported
from straylight.engine.runtime import runtime
from straylight.engine.scheduling import batch_ranges, run_batches
from straylight.engine.roles import ROLE_CODES  # noqa: F401 - re-exported
from straylight.engine.spec import (  # noqa: F401 - re-exported
    AUTO_BATCH_RAYS, TraceSpec, make_spec, scene_epsilon)
from straylight.engine.tallies import chunk_maps  # noqa: F401 - re-exported
from straylight.engine.walk import run_batch, run_batch_reference  # noqa: F401 - re-exported
from straylight.execution import Execution, as_execution
from straylight.progress import progress_bar
from straylight.rng import n_chunks


_MOVED_TO_EXECUTION = ("intersector", "first_chunk")


def _with_deprecated_keywords(ex: Execution, deprecated: dict) -> Execution:
    """``ex`` with the execution keywords ``trace`` used to take loose (``intersector``, ``first_chunk``),
    each with a DeprecationWarning; any other keyword is the TypeError Python would raise."""
    unknown = sorted(set(deprecated) - set(_MOVED_TO_EXECUTION))
    if unknown:
        raise TypeError(f"trace() got an unexpected keyword argument {unknown[0]!r}")
    given = {k: v for k, v in deprecated.items() if v is not None and not (k == "first_chunk" and v == 0)}
    for name in deprecated:
        warnings.warn(f"trace({name}=...) is deprecated and will be removed in the next release: "
                      f"pass execution=Execution({name}=...)", DeprecationWarning, stacklevel=3)
    return replace(ex, **given) if given else ex


def trace(scene, sources, n_rays, seed=0, materials=None, options=None, execution: Execution | None = None,
          **deprecated) -> TraceResult:
    """Trace ``n_rays`` rays from ``sources`` through ``scene``; see docs/engine.md.

    Parameters
    ----------
    scene : geometry.Scene
    sources : a source or a list of sources (straylight.sources)
    n_rays : int
    seed : int, non-negative
    materials : dict name -> Brdf, optional (else ``materials.load_material(name)``)
    options : TraceOptions
    execution : straylight.execution.Execution, optional
        where and how to run (default: in this process): ``threads`` (an in-process thread pool: embree
        and the compiled kernels release the GIL), ``workers``/``client``/``scheduler``/``security`` (dask,
        straylight.engine.backends.dask), ``progress`` (a bar on stderr), ``intersector`` (an intersector
        object to use in-process, e.g. ReferenceIntersector) and ``first_chunk`` (trace the ray ids from
        ``first_chunk * CHUNK_RAYS`` on: continues an earlier trace of ``first_chunk`` whole chunks with the
        same seed; :func:`straylight.analyses.precision.merge_results` pools them exactly)

    ``intersector=`` and ``first_chunk=`` as keywords of ``trace`` are deprecated (one release; a
    DeprecationWarning): give them in ``execution``.
    """
    ex = _with_deprecated_keywords(as_execution(execution), deprecated)
    spec = make_spec(scene, sources, n_rays, seed, materials, options)
    intersector = ex.intersector
    if ex.first_chunk:
        spec = replace(spec, chunk_offset=ex.first_chunk)
    opt = spec.options
    plan = resolve_plan(options or TraceOptions(), spec, intersector)  # which strategies run, and why not
    # on dask, the workers get the spec and build their scenes while this process builds the tables
    slow = any(s.table_ships_early and plan.runs(s.name) for s in registry.STRATEGIES)
    early = None
    if ex.client is not None and slow:
        from straylight.engine.backends.dask import ship_early  # on dask only (scheduling.run_batches says why)

        early = ship_early(ex.client, spec)
    rt = runtime()  # this process's compiled scene and kept tables
    tools = TableTools(runtime=rt, intersector=intersector, run_batch=run_batch, measured={})
    try:  # each table sees the ones before it (the entrance pilot runs with them)
        spec = build_tables(spec, plan, tools, cache=intersector is None)
    except BaseException:
        if early is not None:
            early.release()
        raise
    plan = without_missing_tables(plan, spec, "its table came out empty (its pilot saw no light reach a detector)")
    plan = without_declined(plan, spec)  # a table that says its strategy does not pay here (the eye chains)
    spec = replace(spec, strategies_on=plan.on)  # the walk runs these, and no other
    results = run_batches(spec, batch_ranges(spec), early=early, **ex.trace_keywords())
    totals = BatchTotals(spec)
    with progress_bar(total=n_chunks(spec.n_rays), unit="chunk", enabled=ex.progress) as bar:
        for res in results:  # in chunk order
            bar.update(totals.add(res))
    here = rt.cached_scene(spec)  # this process's scene, if it traced here; else the detectors alone
    result = replace(totals.result(spec, here.detectors if here is not None else detector_samplers(spec)),
                     strategies=plan, unscattered_w=_unscattered(spec, plan))
    from straylight.run_checks import check_truncation

    check_truncation(result, opt.physics.max_events)  # power cut by max_events is not round-off: say so
    if result.paths is not None and hasattr(scene, "names_of"):  # path records answer to every name of a part
        aliases = tuple((alias, p.name) for p in scene.parts for alias in scene.names_of(p)[1:])
        if aliases:
            result = replace(result, paths=replace(result.paths, aliases=aliases))
    return _answering_to_aliases(result, scene)


def _answering_to_aliases(result: TraceResult, scene) -> TraceResult:
    """``result`` whose per-part tables (detectors, absorbed, incident, first_hit, maps) also answer to each part's
    aliases (a CAD solid's instance name, CONTRACTS 6.2); unchanged for a scene without aliases."""
    if not hasattr(scene, "names_of"):
        return result
    unique: dict[str, set[str]] = {}  # alias -> the parts it names
    for p in scene.parts:
        for alias in scene.names_of(p)[1:]:
            unique.setdefault(alias, set()).add(p.name)
    aliases = {a: next(iter(names)) for a, names in unique.items() if len(names) == 1}
    if not aliases:
        return result
    from straylight.paths import AliasDict

    tables: dict[str, Any] = {f: AliasDict(getattr(result, f), aliases) for f in ("detectors", "absorbed", "incident", "first_hit", "maps")
              if isinstance(getattr(result, f, None), dict)}
    return replace(result, **tables)


def _unscattered(spec, plan) -> dict | None:
    """Detector name -> the straight light direct_area computed (the result's ``unscattered_w``), None where it
    did not run."""
    from straylight.engine.direct_area import DirectArea

    table = spec.direct_table
    if not plan.runs("direct_area") or not isinstance(table, DirectArea):
        return None
    return {spec.part_names[table.part]: float(table.power_w)}
