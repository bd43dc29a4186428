"""Engine throughput and variance on the reference baffled tube (shared/BENCHMARK.md).

    .venv/bin/python benchmarks/throughput.py [--rays N] [--quick] [--json OUT.json]

Measured in this one run (the machines are shared and noisy, so only ratios mean much):

1. raw embreex rate: ``EmbreeScene.run`` on 1e6 incoherent rays (random origins inside the tube,
   random directions), 1 process; and on 2 threads (embreex releases the GIL);
2. full-trace rate on the 30 deg stray-light case: (ray segments + NEE shadow rays) per second,
   scatter sampling and all bookkeeping included, in-process (1 worker) and on a dask LocalCluster
   of 2 worker processes (cluster start-up reported separately), and its ratio to the raw rate;
3. ratio(a) = detector power / power through the entrance disk at a = 0, 5, 10, 20, 30 deg with
   its standard error, against BENCHMARK.md's reference values and the geometric direct(a);
4. time to 2 % relative error at 20 and 30 deg, t_2% = t (relerr / 0.02)^2 (t in CPU seconds of this
   single-process run, which other jobs on the machine disturb less than wall time), with next-event
   estimation and for the plain tracer (cosine sampling + roulette, no NEE), and their ratio.
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


def raw_rates(scene, n=1_000_000):
    from straylight.intersect import EmbreeIntersector

    isect = EmbreeIntersector(scene.triangles_mm)
    rng = np.random.default_rng(0)
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


def timed_trace(scene, mats, a_deg, n, seed, nee=True, client=None):
    from straylight.trace import TraceOptions, trace

    opts = TraceOptions(nee=nee, max_events=20 if not nee else 1000)
    t = time.perf_counter()
    c = time.process_time()
    res = trace(scene, source(a_deg), n, seed, materials=mats, options=opts, client=client)
    timed_trace.cpu_s = time.process_time() - c
    return res, time.perf_counter() - t


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rays", type=int, default=400_000, help="rays per NEE run (default 4e5)")
    ap.add_argument("--plain-rays", type=int, default=400_000, help="rays per plain (no NEE) run")
    ap.add_argument("--quick", action="store_true", help="small runs (a smoke test)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    if args.quick:
        args.rays, args.plain_rays = 40_000, 40_000
    from geometry.scenes import reference_scene
    from materials import Lambertian

    out = {}
    t = time.perf_counter()
    scene = reference_scene()
    out["scene_build_s"] = time.perf_counter() - t
    mats = {scene.parts[0].material: Lambertian(0.05)}
    print(f"reference tube: {len(scene.triangles_mm)} triangles, built in {out['scene_build_s']:.1f} s")

    raw1, raw2, raw1_cpu = raw_rates(scene)
    out.update(raw_rate_1=raw1, raw_rate_2threads=raw2, raw_rate_1_cpu=raw1_cpu)
    print(f"raw embreex run, incoherent rays: {raw1 / 1e6:.2f} M/s (1 thread), {raw2 / 1e6:.2f} M/s (2 threads); "
          f"per CPU second {raw1_cpu / 1e6:.2f} M/s")

    res, el = timed_trace(scene, mats, 30.0, args.rays, args.seed)
    rate1 = (res.segments + res.shadow_rays) / el
    cpu1 = timed_trace.cpu_s
    rate1_cpu = (res.segments + res.shadow_rays) / cpu1
    out.update(trace_rate_1=rate1, trace_s_1=el, trace_rate_1_cpu=rate1_cpu)
    print(f"full trace at 30 deg, 1 worker: {args.rays} rays, {res.segments} segments + {res.shadow_rays} shadow "
          f"rays in {el:.2f} s = {rate1 / 1e6:.2f} M rays/s = {rate1 / raw1:.0%} of raw "
          f"(per CPU second: {rate1_cpu / 1e6:.2f} M/s = {rate1_cpu / raw1_cpu:.0%} of raw, less sensitive to load)")

    from dask.distributed import Client, LocalCluster

    t = time.perf_counter()
    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0")
    client = Client(cluster)
    start = time.perf_counter() - t
    timed_trace(scene, mats, 30.0, 2000, args.seed, client=client)  # each worker builds its embree scene
    res2, el2 = timed_trace(scene, mats, 30.0, args.rays, args.seed, client=client)
    client.close()
    cluster.close()
    rate2 = (res2.segments + res2.shadow_rays) / el2
    same = res2.to_json_dict() == res.to_json_dict()
    out.update(trace_rate_2=rate2, cluster_start_s=start, speedup_2_workers=rate2 / rate1, same_numbers_2=same)
    print(f"full trace at 30 deg, 2 workers: {rate2 / 1e6:.2f} M rays/s = {rate2 / raw1:.0%} of 1-thread raw, "
          f"{rate2 / raw2:.0%} of 2-thread raw; speed-up x{rate2 / rate1:.2f} "
          f"(cluster start {start:.1f} s not included); identical numbers: {same}")

    print("\n  a   ratio (NEE)            reference              dev/sigma  direct(a)   t_2%[CPU s]  "
          "plain t_2%[CPU s]  gain")
    out["angles"] = {}
    for a in (0.0, 5.0, 10.0, 20.0, 30.0):
        if a == 30.0:
            r, el = res, cpu1
        else:
            r, _ = timed_trace(scene, mats, a, args.rays, args.seed)
            el = timed_trace.cpu_s  # CPU seconds: robust to other jobs on a shared machine
        det = r.detectors["detector"]
        ratio, err = det.power_w / ENTRANCE_FRACTION, det.stderr_w / ENTRANCE_FRACTION
        ref, ref_err = REFERENCE[a]
        dev = (ratio - ref) / math.hypot(err, ref_err)
        t2 = el * (err / ratio / 0.02) ** 2
        entry = {"ratio": ratio, "stderr": err, "reference": ref, "reference_stderr": ref_err, "dev_sigma": dev,
                 "direct": direct(a), "seconds": el, "t_2pct_s": t2}
        plain = ""
        if a >= 20.0:
            p, _ = timed_trace(scene, mats, a, args.plain_rays, args.seed, nee=False)
            pel = timed_trace.cpu_s
            pdet = p.detectors["detector"]
            if pdet.power_w > 0:
                pt2 = pel * (pdet.stderr_w / pdet.power_w / 0.02) ** 2
                entry.update(plain_ratio=pdet.power_w / ENTRANCE_FRACTION,
                             plain_stderr=pdet.stderr_w / ENTRANCE_FRACTION, plain_t_2pct_s=pt2, gain=pt2 / t2)
                plain = f"{pt2:12.1f}  x{pt2 / t2:6.1f}"
        out["angles"][str(a)] = entry
        print(f"{a:4.0f}  {ratio:.5g} +- {err:.2g}   {ref:.5g} +- {ref_err:.2g}   {dev:+7.2f}   {direct(a):.5f}  "
              f"{t2:9.2f}  {plain}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
