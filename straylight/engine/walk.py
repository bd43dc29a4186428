"""Stage: the walk. One batch of whole chunks, event after event: draw the uniforms, cast the
rays (first triangle), the hit stage (escape, detection, absorption), the surface interaction of
each continuing hit (by kind: straylight.engine.interactions), then absorption, roulette and the
next ray state (straylight.engine.advance). :func:`run_batch` runs it on compiled kernels,
:func:`run_batch_reference` on their numpy twins: the same walk, so the two cannot drift.

Estimators and ledger: docs/engine.md. Every ray starts with weight total power / n_rays (with
entrance sampling: that over the density of its entrance point, straylight.engine.entrance_sampling)."""
from __future__ import annotations

import numpy as np

from straylight.engine.advance import ADVANCE_WRITES_PER_RAY, next_rays
from straylight.engine import diffraction as diffraction_step
from straylight.engine.draws import event_columns, event_uniforms
from straylight.engine.material_groups import distinct
from straylight.engine.emission import emit_batch
from straylight.engine.event import Event, combined_outgoing
from straylight.engine.hits import HITS_WRITES_PER_RAY, Hits
from straylight.engine.interactions import Capability, PartCapabilities, part_handlers
from straylight.engine.kernel_sets import COMPILED, NUMPY
from straylight.engine.options import TraceError, walk_settings
from straylight.engine.plan import running as running_strategies
from straylight.engine.ray_batch import EVENT_DETECTOR, emitted_rays
from straylight.engine.ray_log import RayLogger
from straylight.engine.runtime import runtime
from straylight.engine.spec import TraceSpec
from straylight.engine.strategies.base import NEE_HOOKS, BatchContext, overrides
from straylight.engine.strategies import registry
from straylight.engine.tallies import DetectorRecords, batch_sums
from straylight.paths import mix_key
from straylight.rng import CHUNK_RAYS

def part_interactions(spec: TraceSpec):
    """(index of each part's handler (P,), the handlers, those of continuing hits) for the parts of
    ``spec``: a part's handler is its interaction kind's for its material (registry.part_handlers: the
    kind itself, or the algorithm ``surface_response`` uses for that class of material), in the order
    the parts first use them."""
    kinds, of_part = [], []
    try:
        per_part = part_handlers(spec)
    except ValueError as exc:
        raise TraceError(str(exc)) from None
    for kind in per_part:
        if kind not in kinds:
            kinds.append(kind)
        of_part.append(kinds.index(kind))
    continuing = sorted({k for k in of_part if not kinds[k].terminal})
    return np.array(of_part, dtype=np.int64), kinds, continuing


def _by_interaction(kind_of_part, kinds, continuing, part):
    """(handler, selection of the continuing hits) per handler present; a slice when one has them all."""
    if len(continuing) == 1:  # one handler in the scene for every continuing hit
        return [(kinds[continuing[0]], slice(None))]
    k = kind_of_part[part]
    if len(k) and (k == k[0]).all():
        return [(kinds[k[0]], slice(None))]
    return [(kinds[u], np.flatnonzero(k == u)) for u in distinct(k)]


def _record_walk_hits(event, rec, rec_w):
    """Map (and path) records of the counted random-walk hits on detectors."""
    rays, hit, scene = event.rays, event.hits, event.scene
    dj = scene.arrays.detector_of_part[hit.part[rec]]
    for j in range(len(scene.det_parts)):
        sel = dj == j
        if sel.any():
            r = rec[sel]
            keys = mix_key(rays.path_key[r], scene.det_parts[j] * 4 + EVENT_DETECTOR) if event.settings.record_paths \
                else None
            events = rays.history[r] if event.settings.record_paths else None
            event.records.add(j, rays.ray[r], hit.point_mm[r], rec_w[sel], keys, events, rays.depth[r])


def walk(spec: TraceSpec, first_chunk: int, stop_chunk: int, intersector, kernels) -> dict:
    """Trace chunks ``first_chunk .. stop_chunk-1`` with the kernel set ``kernels``; returns per-chunk
    sums (straylight.engine.tallies.batch_sums)."""
    scene = runtime().scene(spec, intersector)
    opt = spec.options
    rows = spec.rows
    n = min(stop_chunk * CHUNK_RAYS, spec.n_rays) - first_chunk * CHUNK_RAYS
    draws = kernels.draws(spec.seed, spec.chunk_offset + first_chunk, spec.chunk_offset + stop_chunk)  # chunk_rng's
    w0 = spec.total_power_w / spec.n_rays
    kind_of_part, kinds, continuing = part_interactions(spec)
    capabilities = PartCapabilities(kinds[k] for k in kind_of_part)
    settings = walk_settings(opt, spec.eps, w0, capabilities.parts(Capability.NEE))
    reuse = kernels.reuse_buffers
    if reuse:
        tallies = scene.thread_local("tallies", lambda: kernels.tallies(rows.n_per_ray, n)).reset(rows.n_per_ray, n)
    else:
        tallies = kernels.tallies(rows.n_per_ray, n)
    records = DetectorRecords(scene.detectors, scene.det_parts, tuple(int(b) for b in opt.output.map_bins),
                              settings.record_paths)
    ctx = BatchContext(spec=spec, scene=scene, n_rays=n, start_weight_w=w0, tallies=tallies, rows=rows,
                       records=records, capabilities=capabilities, first_chunk=first_chunk, stop_chunk=stop_chunk)
    on = running_strategies(spec, intersector)  # the plan's: a strategy it turned off does not run
    running = []  # (strategy, its state for this batch), in registry order
    for strategy in registry.STRATEGIES:
        if strategy.name not in on:
            continue
        state = strategy.batch_state(ctx)
        if state is not None:
            running.append((strategy, state))
    states = {s.state_key: state for s, state in running if s.state_key is not None}
    second_lobe = spec.critical_table is not None and bool(opt.estimator.second_vertex_lobe_sampling)
    columns = event_columns(rows.n_detectors, opt.estimator.nee_samples, scene.target is not None,
                            spec.critical_table is not None, second_lobe,
                            [(s.name, s.uniform_columns(spec)) for s, _ in running if overrides(s, "uniform_columns")])
    ubuf = scene.scratch("uniforms", n * max(5, columns.width)) if reuse else None  # refilled every event
    nee_hooks = tuple((s, state) for s, state in running if any(overrides(s, h) for h in NEE_HOOKS))
    vertex_hooks = tuple((s, state) for s, state in running if overrides(s, "vertex_weights"))
    interface_hooks = tuple((s, state) for s, state in running if overrides(s, "at_interfaces"))
    shadow_test = diffraction_step.shadow_test(spec.diffraction, scene)
    start = next((state for s, state in running if s.shapes_emission), None)  # e.g. entrance sampling
    rays = emitted_rays(*emit_batch(spec, draws, n, ubuf, start), w0 if start is None else start.weights,
                        opt.output.path_depth, settings.record_paths)
    logged = min(int(opt.output.ray_log) - first_chunk * CHUNK_RAYS, n)  # rays of this batch in the ray log
    ray_log = RayLogger(logged, first_chunk * CHUNK_RAYS, scene.arrays.part_roles) if logged > 0 else None
    segments = shadow_rays = 0
    max_events = int(opt.physics.max_events)
    diff = spec.diffraction
    skip = None  # per live ray: the edge ids it was just diffracted at (diffraction only)
    for ev in range(max_events):
        if len(rays.ray) == 0:
            break
        U = event_uniforms(draws, rays.ray, columns.width, ubuf)
        tri = np.asarray(scene.isect.first_triangle(rays.origin_mm, rays.direction))
        segments += len(rays.ray)
        bent = None
        if diff is not None:  # rays that pass a diffracting edge before their hit bend there (HURB)
            split = diffraction_step.divert(diff, scene, rays, tri, skip, U, columns.sample, settings.record_paths)
            if split is not None:
                keep, bent, bent_skip, vertex = split
                if ray_log is not None:
                    ray_log.bends(ev, rays, keep, bent)
                rays, tri, U = diffraction_step.subset(rays, keep), tri[keep], U[keep]
                if settings.nee and rows.n_detectors > 0:
                    shadow_rays += diffraction_step.next_event(diff, scene, bent, bent_skip, vertex, columns, settings,
                                                               tallies, rows, records)
                if ev == max_events - 1:
                    diffraction_step.truncate(bent, tallies, rows)
                    bent = None
        tallies.reserve(HITS_WRITES_PER_RAY * len(tri))
        hit = Hits(*kernels.hits(tri, rays, scene.arrays, rows, settings, tallies.kernel_arg))
        if ray_log is not None:
            ray_log.segments(ev, rays, tri, hit, scene.arrays.triangle_part, spec)
        event = Event(spec=spec, scene=scene, kernels=kernels, settings=settings, rows=rows, tallies=tallies,
                      records=records, rays=rays, tri=tri, hits=hit, uniforms=U, columns=columns,
                      capabilities=capabilities, states=states, nee_hooks=nee_hooks,
                      vertex_hooks=vertex_hooks, interface_hooks=interface_hooks, shadow_test=shadow_test)
        rec, rec_w = hit.detected, hit.detected_w
        for strategy, state in running:  # walk hits a strategy also counts keep their share
            if len(rec):
                rec, rec_w = strategy.share_walk_hits(state, event, rec, rec_w)
        if len(rec):
            _record_walk_hits(event, rec, rec_w)
        cont = hit.continuing
        for strategy, state in running:
            strategy.after_hits(state, event, cont)
        if len(cont) == 0:
            if bent is not None:
                rays, skip = bent, bent_skip
                continue
            break
        groups = _by_interaction(kind_of_part, kinds, continuing, hit.part[cont])
        if len(groups) == 1:
            out = groups[0][0].interact(event, groups[0][1])
        else:
            out = combined_outgoing(len(cont), [(sel, kind.interact(event, sel)) for kind, sel in groups])
        for strategy, state in running:
            strategy.after_interactions(state, event, cont, out)
        shadow_rays += event.shadow_rays
        tallies.reserve(ADVANCE_WRITES_PER_RAY * len(cont))
        # the roulette column as its own array: one compiled advance (a column view is typed 'A', or 'C' when it
        # has one row: each layout is a kernel of its own to load, ~8 ms)
        roulette_u = np.ascontiguousarray(U[:, columns.roulette])
        rays, _kept = next_rays(kernels.advance(cont, out, rays, hit, roulette_u, settings,
                                                ev == max_events - 1, tallies.kernel_arg, rows))
        if diff is not None:
            skip = np.full((len(rays.ray), 3), -1, dtype=np.int64)
            if bent is not None:
                rays, skip = diffraction_step.merge(rays, skip, bent, bent_skip)
    for strategy, state in running:
        shadow_rays += strategy.after_walk(state, ctx)
    return batch_sums(tallies, rows, first_chunk, records, segments, shadow_rays,
                      None if ray_log is None else ray_log.piece())


def run_batch(spec: TraceSpec, first_chunk: int, stop_chunk: int, intersector=None) -> dict:
    """Trace chunks ``first_chunk .. stop_chunk-1`` on the compiled kernels; returns per-chunk sums.

    Materials, sources, random draws and ray casts are called once per event on contiguous arrays;
    :func:`run_batch_reference` is the numpy twin it is tested against (bit-identical)."""
    return walk(spec, first_chunk, stop_chunk, intersector, COMPILED)


def run_batch_reference(spec: TraceSpec, first_chunk: int, stop_chunk: int, intersector=None) -> dict:
    """The same walk on the vectorised-numpy twins of the kernels and numpy's Generator (the slow
    reference the compiled path is tested against: same random streams, same arithmetic order)."""
    if spec.vertex_table is not None:
        raise TraceError("the numpy reference engine does not implement first_vertex_sampling")
    return walk(spec, first_chunk, stop_chunk, intersector, NUMPY)
