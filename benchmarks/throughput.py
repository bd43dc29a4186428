"""Engine throughput and variance on the reference baffled tube (shared/BENCHMARK.md).

    .venv/bin/python benchmarks/throughput.py [--rays N] [--quick] [--seed S] [--json OUT.json] [--rates-only]
    .venv/bin/python benchmarks/throughput.py --scene SCENE.toml [--rays N]   (items 1-2 on that scene, 1 worker)

Everything is measured in this one run and printed as ratios, because the machines are shared
(load 4-7 on 2 cores) and absolute rates move with the neighbours:

1. raw embreex rate: ``EmbreeScene.run`` on 1e6 incoherent rays (random origins inside the tube,
   random directions), 1 process; and on 2 threads (embreex releases the GIL);
2. full-trace rate on the 30 deg stray-light case: (ray segments + NEE shadow rays) per second,
   scatter sampling and all bookkeeping included, in-process (1 worker), on the dask LocalCluster that
   ``--workers 2`` starts (1 process x 2 threads; its rate against the 2-thread raw rate), on 2 threads
   in-process, and on a LocalCluster of 2 worker processes with 1 thread each (cluster start-up and
   worker warm-up timed separately and excluded from the steady-state rates), with the ratios to the
   raw rate; the share of the 1-worker CPU time spent inside the embree queries (what bounds that
   ratio) and the CPU per cast of the rest; and raw embreex on the trace's own rays (every batch of
   segments and shadow rays the 1-worker trace cast, replayed through ``EmbreeScene.run``), with the
   full trace's ratio to that too (both ratios are printed; the target is set on the first);
3. ratio(a) = detector power / power through the entrance disk at a = 0, 5, 10, 20, 30 deg with
   its standard error, against BENCHMARK.md's reference values and the geometric direct(a);
4. time to 2 % relative error at 20 and 30 deg, t_2% = t (relerr / 0.02)^2, with next-event
   estimation and for the plain tracer (cosine sampling + roulette, no NEE), and their ratio.

Each rate is measured ``--repeats`` times (default 3) and the least disturbed (fastest) kept.
Which clock: rates are given per CPU second (``time.process_time`` of this process; on 2 workers,
the CPU seconds of each worker process, read through ``client.run``) AND per wall second. The CPU
figures are the ones to compare, since other jobs steal wall time but not CPU time; the 2-worker
speed-up is reported both as wall time (meaningful only on an idle machine) and as CPU time of the
1-worker run / CPU time of the busiest worker (what the split gives when each worker has a core).
The mesh is ``reference_scene(tolerance_mm=0.01)`` (~15k triangles, close to BENCHMARK.md's 17k),
fine enough that the 84-sided vane holes do not bias the direct part of ratio(a).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import threading
import time

import numpy as np

REFERENCE = {0.0: (0.48979, 0.00030), 5.0: (0.27618, 0.00027), 10.0: (0.08946, 0.00017),
             20.0: (9.02e-06, 0.29e-06), 30.0: (4.41e-06, 0.09e-06)}
ENTRANCE_FRACTION = (50.0 / 60.0) ** 2  # source disk r 60 fully covers the (shifted) entrance r 50


def direct(a_deg):
    """Geometric direct transmission through the top vane's r = 35 hole (BENCHMARK.md)."""
    s = 280.5 * math.tan(math.radians(a_deg))
    if s >= 70.0:
        return 0.0
    return (2 * 35 ** 2 * math.acos(s / 70) - (s / 2) * math.sqrt(70 ** 2 - s ** 2)) / (math.pi * 50 ** 2)


def source(a_deg):
    from straylight.sources import CollimatedDisk

    a = math.radians(a_deg)
    return CollimatedDisk([0, 0, 310], [0, 0, -1], [math.sin(a), 0, -math.cos(a)], 60.0, power_w=1.0)


SCENE_SOURCES = []  # --scene: the scene file's sources replace the tube's beam


def raw_rates(scene, n=1_000_000):
    """Raw embreex on incoherent rays: inside the tube (r < 50, 0 < z < 300), or for a --scene in
    the middle half of its bounding box (as benchmarks/worker_scaling.py), random directions."""
    from straylight.intersect import EmbreeIntersector

    isect = EmbreeIntersector(scene.triangles_mm)
    rng = np.random.default_rng(0)
    if SCENE_SOURCES:
        tri = np.asarray(scene.triangles_mm).reshape(-1, 3)
        lo, hi = tri.min(axis=0), tri.max(axis=0)
        o = (lo + (hi - lo) * (0.25 + 0.5 * rng.random((n, 3)))).astype(np.float32)
    else:
        r = 50 * np.sqrt(rng.random(n))
        ph = 2 * np.pi * rng.random(n)
        o = np.stack([r * np.cos(ph), r * np.sin(ph), 300 * rng.random(n)], 1).astype(np.float32)
    d = rng.normal(size=(n, 3))
    d = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
    isect._scene.run(o[:10000], d[:10000])
    t = time.perf_counter()
    c = time.process_time()
    isect._scene.run(o, d)
    one = n / (time.perf_counter() - t)
    one_cpu = n / (time.process_time() - c)
    half = n // 2
    threads = [threading.Thread(target=isect._scene.run, args=(o[k * half:(k + 1) * half], d[k * half:(k + 1) * half]))
               for k in range(2)]
    t = time.perf_counter()
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    two = n / (time.perf_counter() - t)
    return one, two, one_cpu


def timed_trace(scene, mats, a_deg, n, seed, nee=True, client=None, threads=None, workers=None):
    """Trace; returns (result, wall s, CPU s of this process)."""
    from straylight.execution import Execution
    from straylight.trace import EstimatorOptions, PhysicsOptions, TraceOptions, trace

    opts = TraceOptions(estimator=EstimatorOptions(nee=nee), physics=PhysicsOptions(max_events=20 if not nee else 1000))
    t = time.perf_counter()
    c = time.process_time()
    res = trace(scene, SCENE_SOURCES or source(a_deg), n, seed, materials=mats, options=opts,
                execution=Execution(client=client, threads=threads, workers=workers))
    return res, time.perf_counter() - t, time.process_time() - c


def embree_share(scene, mats, a_deg, n, seed):
    """CPU seconds of one 1-worker trace and the part spent inside the embree queries (first hit and
    occlusion, float32 conversion included), timed by wrapping the intersector's two methods for this
    run: the full-trace / raw ratio cannot exceed (raw ratio) x total / embree. Also the rays it cast
    (segments and shadow rays, as float32 batches in the order the trace cast them), for
    :func:`raw_on_trace_rays`."""
    from straylight.intersect.embree import EmbreeIntersector

    spent = [0.0]
    cast = {"first_triangle": [], "occluded": []}
    saved = {name: getattr(EmbreeIntersector, name) for name in ("first_triangle", "occluded")}

    def timed(name, method):
        def wrapper(self, *args):
            c = time.process_time()
            out = method(self, *args)
            spent[0] += time.process_time() - c
            cast[name].append(tuple(np.array(a, dtype=np.float32) for a in args))
            return out
        return wrapper

    try:
        for name, method in saved.items():
            setattr(EmbreeIntersector, name, timed(name, method))
        _, _, total = timed_trace(scene, mats, a_deg, n, seed)
    finally:
        for name, method in saved.items():
            setattr(EmbreeIntersector, name, method)
    return total, spent[0], cast


def raw_on_trace_rays(scene, cast, repeats=3):
    """Raw embreex on the trace's own rays: ``EmbreeScene.run`` on exactly the batches the trace cast
    (segments as first-hit queries, shadow rays as occlusion queries with their tmax), float32 arrays
    prepared beforehand, in the trace's order; best of ``repeats``. Returns (casts per CPU second,
    segment rate, shadow-ray rate). The same honest baseline as the incoherent random rays of
    :func:`raw_rates`, but on the trace's ray distribution (long collimated first segments, short
    wall-to-wall scatter segments, shadow rays aimed at the detector)."""
    from straylight.intersect import EmbreeIntersector

    run = EmbreeIntersector(scene.triangles_mm)._scene.run
    segs, shadows = cast["first_triangle"], cast["occluded"]
    run(*segs[0])  # warm

    def best(fn):
        t = math.inf
        for _ in range(repeats):
            c = time.process_time()
            fn()
            t = min(t, time.process_time() - c)
        return t

    t_seg = best(lambda: [run(o, d) for o, d in segs])
    t_sh = best(lambda: [run(o, d, dists=t, query="OCCLUDED") for o, d, t in shadows]) if shadows else 0.0
    n_seg = sum(len(o) for o, _ in segs)
    n_sh = sum(len(o) for o, _, _ in shadows)
    return (n_seg + n_sh) / (t_seg + t_sh), n_seg / t_seg, (n_sh / t_sh if n_sh else float("nan"))


def compiled_vs_numpy(scene, mats, a_deg, n, seed):
    """CPU seconds of the compiled engine (run_batch) and of its numpy twin (run_batch_reference,
    the engine before the kernels) on the same batches, interleaved; and whether the sums agree bit for bit."""
    from straylight.rng import batches
    from straylight.trace import AUTO_BATCH_RAYS, TraceOptions, make_spec, run_batch, run_batch_reference

    spec = make_spec(scene, source(a_deg), n, seed, mats, TraceOptions())
    t_fast = t_ref = 0.0
    same = True
    for a, b in batches(n, spec.options.batch_rays or AUTO_BATCH_RAYS):
        c = time.process_time()
        fast = run_batch(spec, a, b)
        t_fast += time.process_time() - c
        c = time.process_time()
        ref = run_batch_reference(spec, a, b)
        t_ref += time.process_time() - c
        same &= bool(np.array_equal(fast["s1"], ref["s1"]) and np.array_equal(fast["s2"], ref["s2"]))
    return t_fast, t_ref, same


def two_workers(scene, mats, a_deg, n, seed, repeats=1):
    """The same trace on a LocalCluster of 2 processes x 1 thread; start-up timed apart."""
    from dask.distributed import Client

    from straylight.engine.backends.dask import local_cluster, warm_up, worker_cpu_seconds
    from straylight.trace import TraceOptions, make_spec

    t = time.perf_counter()
    cluster = local_cluster(2, processes=True)  # 2 processes (Execution(workers=2) now uses threads)
    client = Client(cluster)
    start_s = time.perf_counter() - t
    t = time.perf_counter()
    # each worker builds its embree scene and loads the compiled kernels once
    warm_up(client, make_spec(scene, source(a_deg), n, seed, mats, TraceOptions()))
    warm_s = time.perf_counter() - t
    best = None
    for _ in range(repeats):  # keep the least disturbed repeat (smallest busiest-worker CPU time)
        before = worker_cpu_seconds(client)
        res, wall, own_cpu = timed_trace(scene, mats, a_deg, n, seed, client=client)
        after = worker_cpu_seconds(client)
        cpu = {w: after[w] - before[w] for w in after}
        if best is None or max(cpu.values()) < max(best[3].values()):
            best = (res, wall, own_cpu, cpu)
    client.close()
    cluster.close()
    return best + (start_s, warm_s)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rays", type=int, default=400_000, help="rays per NEE run (default 4e5)")
    ap.add_argument("--plain-rays", type=int, default=400_000, help="rays per plain (no NEE) run")
    ap.add_argument("--quick", action="store_true", help="small runs (a smoke test)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=3,
                    help="rate measurements repeated, the least disturbed kept (default 3)")
    ap.add_argument("--json", default=None)
    ap.add_argument("--scene", default=None,
                    help="a scene file (its sources and materials) instead of the tube at 30 deg; implies --rates-only")
    ap.add_argument("--rates-only", action="store_true",
                    help="stop after the 1-worker rates (raw, full trace, embree share, raw on the trace's rays)")
    args = ap.parse_args(argv)
    if args.quick:
        args.rays, args.plain_rays = 60_000, 40_000
    out = {"rays": args.rays, "seed": args.seed}
    t = time.perf_counter()
    if args.scene:
        from straylight.scene import load_scene

        args.rates_only = True
        rs = load_scene(args.scene)
        scene, mats = rs.scene, rs.materials
        SCENE_SOURCES[:] = list(rs.sources)
        label = args.scene
    else:
        from geometry.scenes import reference_scene
        from materials import Lambertian

        scene = reference_scene(tolerance_mm=0.01)
        mats = {scene.parts[0].material: Lambertian(0.05)}
        label = "reference tube"
    out["scene_build_s"] = time.perf_counter() - t
    out["triangles"] = len(scene.triangles_mm)
    out["scene"] = label
    print(f"{label}: {len(scene.triangles_mm)} triangles, loaded in {out['scene_build_s']:.1f} s")

    # shared machine: repeat each rate measurement and keep the least disturbed one (fastest)
    raws = [raw_rates(scene) for _ in range(args.repeats)]
    raw1, raw2, raw1_cpu = max(r[0] for r in raws), max(r[1] for r in raws), max(r[2] for r in raws)
    out.update(raw_rate_1=raw1, raw_rate_2threads=raw2, raw_rate_1_cpu=raw1_cpu)
    print(f"raw embreex run, incoherent rays, 1 process: {raw1_cpu / 1e6:.2f} M/CPU-s, {raw1 / 1e6:.2f} M/wall-s; "
          f"2 threads: {raw2 / 1e6:.2f} M/wall-s")

    timed_trace(scene, mats, 30.0, 2000, args.seed)  # build the embree scene, load the compiled kernels
    runs = [timed_trace(scene, mats, 30.0, args.rays, args.seed) for _ in range(args.repeats)]
    res, el, cpu1 = runs[0][0], min(r[1] for r in runs), min(r[2] for r in runs)
    casts = res.segments + res.shadow_rays
    rate1, rate1_cpu = casts / el, casts / cpu1
    out.update(trace_casts=casts, trace_s_1=el, trace_cpu_s_1=cpu1, trace_rate_1=rate1, trace_rate_1_cpu=rate1_cpu,
               trace_ratio_1_cpu=rate1_cpu / raw1_cpu, trace_ratio_1_wall=rate1 / raw1)
    print(f"full trace{'' if args.scene else ' at 30 deg'}, 1 worker: {args.rays} rays, {res.segments} segments + {res.shadow_rays} shadow rays"
          f"\n    {rate1_cpu / 1e6:.2f} M/CPU-s = {rate1_cpu / raw1_cpu:.0%} of raw (CPU);  "
          f"{rate1 / 1e6:.2f} M/wall-s = {rate1 / raw1:.0%} of raw (wall)")

    total_s, embree_s, cast = embree_share(scene, mats, 30.0, args.rays, args.seed)
    out.update(embree_share_cpu=embree_s / total_s)
    print(f"    of which embree queries: {embree_s:.2f} of {total_s:.2f} CPU s ({embree_s / total_s:.0%}); "
          f"the rest (sampling, kernels, draws, tallies, glue) costs {(total_s - embree_s) / casts * 1e6:.2f} us/cast")
    own, own_seg, own_sh = raw_on_trace_rays(scene, cast, args.repeats)
    del cast
    out.update(raw_rate_trace_rays_cpu=own, raw_rate_trace_segments_cpu=own_seg, raw_rate_trace_shadow_cpu=own_sh,
               trace_ratio_1_cpu_trace_rays=rate1_cpu / own)
    print(f"    raw embreex on the trace's own rays (same batches, same order): {own / 1e6:.2f} M/CPU-s "
          f"(segments {own_seg / 1e6:.2f}, shadow rays {own_sh / 1e6:.2f}); full trace = {rate1_cpu / own:.0%} of it "
          f"(vs {rate1_cpu / raw1_cpu:.0%} of raw on random rays)")

    if not args.scene:
        t_fast, t_ref, same_ref = compiled_vs_numpy(scene, mats, 30.0, args.rays, args.seed)
        out.update(compiled_cpu_s=t_fast, numpy_reference_cpu_s=t_ref, compiled_speedup=t_ref / t_fast,
                   compiled_bit_identical=same_ref)
        print(f"    compiled kernels vs the numpy engine (run_batch_reference), same batches interleaved: "
              f"x{t_ref / t_fast:.2f} less CPU ({t_ref:.2f} -> {t_fast:.2f} s); bit-identical sums: {same_ref}")

    if args.rates_only:
        print(f"\nsummary (same run): full trace = {out['trace_ratio_1_cpu']:.0%} of raw embreex on random rays, "
              f"{out['trace_ratio_1_cpu_trace_rays']:.0%} of raw embreex on the trace's own rays (1 worker, CPU time)")
        if args.json:
            with open(args.json, "w") as fh:
                json.dump(out, fh, indent=2)
        return 0

    res2, el2, own2, wcpu, start_s, warm_s = two_workers(scene, mats, 30.0, args.rays, args.seed, args.repeats)
    same = res2.to_json_dict() == res.to_json_dict()
    rate2 = casts / el2
    busiest = max(wcpu.values())
    rate2_cpu = casts / sum(wcpu.values())
    speed_cpu = cpu1 / busiest
    out.update(cluster_start_s=start_s, worker_warmup_s=warm_s, trace_s_2=el2, trace_rate_2=rate2,
               worker_cpu_s=list(wcpu.values()), client_cpu_s_2=own2, trace_rate_2_cpu_per_worker=rate2_cpu,
               trace_ratio_2_cpu=rate2_cpu / raw1_cpu, speedup_2_wall=el / el2, speedup_2_cpu=speed_cpu,
               same_numbers_2=same)
    print(f"full trace at 30 deg, 2 workers (dask, 2 processes x 1 thread; cluster start {start_s:.1f} s and "
          f"per-worker warm-up {warm_s:.1f} s not included):"
          f"\n    worker CPU s {', '.join(f'{c:.2f}' for c in wcpu.values())} (client process {own2:.2f}); "
          f"{rate2_cpu / 1e6:.2f} M/CPU-s per worker = {rate2_cpu / raw1_cpu:.0%} of raw (CPU)"
          f"\n    speed-up over 1 worker: x{speed_cpu:.2f} by CPU time (1-worker CPU / busiest worker CPU), "
          f"x{el / el2:.2f} by wall time ({rate2 / 1e6:.2f} M/wall-s = {rate2 / raw2:.0%} of 2-thread raw); "
          f"identical numbers: {same}")
    print(f"    with start-up included: x{el / (el2 + start_s + warm_s):.2f} by wall time")

    from dask.distributed import Client

    from straylight.engine.backends.dask import local_cluster

    with local_cluster(2) as cluster, Client(cluster) as client:  # what Execution(workers=2) starts
        timed_trace(scene, mats, 30.0, 20_000, args.seed, client=client)  # warm-up
        druns = [timed_trace(scene, mats, 30.0, args.rays, args.seed, client=client) for _ in range(args.repeats)]
    el_d = min(r[1] for r in druns)
    cpu_d = min(r[2] for r in druns)  # CPU of the whole process: both worker threads, scheduler, client
    same_d = druns[0][0].to_json_dict() == res.to_json_dict()
    rate_d = casts / el_d
    out.update(trace_s_dask_threads=el_d, trace_cpu_s_dask_threads=cpu_d, speedup_dask_threads_wall=el / el_d,
               trace_rate_dask_threads=rate_d, trace_ratio_dask_threads_wall=rate_d / raw2,
               same_numbers_dask_threads=same_d)
    print(f"full trace at 30 deg, dask LocalCluster default (--workers 2 = 1 in-process worker, a pool of 2 threads per task): "
          f"speed-up x{el / el_d:.2f} by wall time; {rate_d / 1e6:.2f} M/wall-s = {rate_d / raw2:.0%} of 2-thread raw "
          f"(wall); CPU {cpu_d:.2f} s in all = x{cpu_d / cpu1:.2f} of 1 worker; identical numbers: {same_d}")

    # as a user runs it: trace(..., execution=Execution(workers=K)) = `straylight trace --workers K`, each call starting and
    # closing its own LocalCluster (start-up, scatter and shutdown included; dask already imported)
    user = {k: min(timed_trace(scene, mats, 30.0, args.rays, args.seed, workers=k)[1] for _ in range(args.repeats))
            for k in (1, 2)}
    out.update(user_wall_s_workers1=user[1], user_wall_s_workers2=user[2], speedup_user_wall=user[1] / user[2])
    print(f"as a user runs it (Execution(workers=K) = --workers K, cluster start-up and shutdown included): "
          f"--workers 1 {user[1]:.2f} s, --workers 2 {user[2]:.2f} s: x{user[1] / user[2]:.2f} "
          f"(in-process 1 worker {el:.2f} s: x{el / user[2]:.2f})")

    truns = [timed_trace(scene, mats, 30.0, args.rays, args.seed, threads=2) for _ in range(args.repeats)]
    el_t, cpu_t = min(r[1] for r in truns), min(r[2] for r in truns)
    same_t = truns[0][0].to_json_dict() == res.to_json_dict()
    out.update(trace_s_2threads=el_t, trace_cpu_s_2threads=cpu_t, speedup_2threads_wall=el / el_t,
               same_numbers_2threads=same_t)
    print(f"full trace at 30 deg, 2 threads in one process (Execution(threads=2)): {casts / el_t / 1e6:.2f} M/wall-s, "
          f"speed-up x{el / el_t:.2f} by wall time (raw embreex 2 threads: x{raw2 / raw1:.2f}); CPU {cpu_t:.2f} s "
          f"in all (1 thread: {cpu1:.2f} s); identical numbers: {same_t}")

    print("\n  a   ratio (NEE)            reference              dev/sigma  direct(a)   t_2%[CPU s]  "
          "plain t_2%[CPU s]  gain")
    out["angles"] = {}
    for a in (0.0, 5.0, 10.0, 20.0, 30.0):
        if a == 30.0:
            r, el_a = res, cpu1
        else:
            r, _, el_a = timed_trace(scene, mats, a, args.rays, args.seed)
        det = r.detectors["detector"]
        ratio, err = det.power_w / ENTRANCE_FRACTION, det.stderr_w / ENTRANCE_FRACTION
        ref, ref_err = REFERENCE[a]
        dev = (ratio - ref) / math.hypot(err, ref_err)
        t2 = el_a * (err / ratio / 0.02) ** 2
        entry = {"ratio": ratio, "stderr": err, "reference": ref, "reference_stderr": ref_err, "dev_sigma": dev,
                 "direct": direct(a), "cpu_s": el_a, "t_2pct_s": t2}
        plain = ""
        if a >= 20.0:
            p, _, pel = timed_trace(scene, mats, a, args.plain_rays, args.seed, nee=False)
            pdet = p.detectors["detector"]
            if pdet.power_w > 0:
                pt2 = pel * (pdet.stderr_w / pdet.power_w / 0.02) ** 2
                entry.update(plain_ratio=pdet.power_w / ENTRANCE_FRACTION,
                             plain_stderr=pdet.stderr_w / ENTRANCE_FRACTION, plain_t_2pct_s=pt2, gain=pt2 / t2)
                plain = f"{pt2:12.1f}  x{pt2 / t2:6.1f}"
        out["angles"][str(a)] = entry
        print(f"{a:4.0f}  {ratio:.5g} +- {err:.2g}   {ref:.5g} +- {ref_err:.2g}   {dev:+7.2f}   {direct(a):.5f}  "
              f"{t2:9.2f}  {plain}")
    print("\nsummary (same run): full trace / raw embreex = "
          f"{out['trace_ratio_1_cpu']:.0%} on 1 worker (CPU time; target >= 60 %), "
          f"{out['trace_ratio_1_cpu_trace_rays']:.0%} of raw embreex on the trace's own rays; speed-up 1 -> 2 workers "
          f"(target >= 1.8): dask default (2 threads) x{out['speedup_dask_threads_wall']:.2f} "
          f"(= {out['trace_ratio_dask_threads_wall']:.0%} of 2-thread raw, target >= 50 %), in-process threads "
          f"x{out['speedup_2threads_wall']:.2f} (wall); --workers 1 -> 2 with cluster start-up "
          f"x{out['speedup_user_wall']:.2f}; 2 dask processes x{speed_cpu:.2f} (CPU) / x{el / el2:.2f} (wall)")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
