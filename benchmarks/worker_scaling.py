"""Worker-process scaling on dask (issue #17), each run timed whole, in one run of this script.

    .venv/bin/python benchmarks/worker_scaling.py [--scene SCENE.toml] [--rays N] [--seed S] [--json OUT]

For K = 1 and 2: a LocalCluster of K worker processes with one thread each (bound to 127.0.0.1,
as ``straylight.distribute.local_cluster(K, processes=True)``), one trace of ``--rays`` rays,
cluster closed: the wall time of all of it (start-up, scene shipped to and built in each worker,
compiled kernels loaded from numba's cache, tracing, shutdown) and the ratio K=1 / K=2. Also the
per-process rate: ray casts (segments + shadow rays) per CPU second of each worker process, against
raw embreex's rate measured in this run on the same scene (``EmbreeScene.run`` on incoherent rays,
1 thread), counted from after the workers' start-up (imports, scene built, kernels loaded: timed
apart), and the same trace in this process for comparison. Numbers must be identical for K = 1,
2 and in-process (printed).

Each K runs in a fresh Python process of this script (``--one K``), its clock started just before
the cluster: the worker processes are forked from a server that imports the engine and loads the
kernels once (``straylight.distribute``), which a second cluster in the same process would reuse;
a fresh process gives every K its full start-up. The phases are printed: start-up (cluster up,
scene scattered and built, kernels loaded), trace, close.

Default scene: the reference tube (``geometry.scenes.reference_scene(0.01)``, 15k triangles, 30 deg).
The machine may be shared: the wall-time ratio is meaningful only when two cores are free; the
CPU-time rates are not disturbed by neighbours.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np


def raw_rate(triangles_mm, n=1_000_000):
    """Raw embreex first-hit rate per CPU second on incoherent rays inside the scene's bounding box."""
    from straylight.intersect import EmbreeIntersector

    isect = EmbreeIntersector(triangles_mm)
    rng = np.random.default_rng(0)
    lo, hi = triangles_mm.reshape(-1, 3).min(axis=0), triangles_mm.reshape(-1, 3).max(axis=0)
    o = (lo + (hi - lo) * (0.25 + 0.5 * rng.random((n, 3)))).astype(np.float32)
    d = rng.normal(size=(n, 3))
    d = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
    isect._scene.run(o[:10000], d[:10000])
    best = 0.0
    for _ in range(3):
        c = time.process_time()
        isect._scene.run(o, d)
        best = max(best, n / (time.process_time() - c))
    return best


def whole_run(k, scene, sources, materials, n, seed, options):
    """Start K worker processes, trace, close: (result, wall s, worker CPU s of the trace itself
    (after start-up: imports, scene shipped and built, kernels loaded), start-up wall s, close wall s)."""
    from dask.distributed import Client

    from straylight.distribute import local_cluster, warm_up, worker_cpu_seconds
    from straylight.trace import make_spec, trace

    t = time.perf_counter()
    with local_cluster(k, processes=True) as cluster, Client(cluster) as client:
        # what the first trace's tasks would do anyway: each worker builds the scene, loads the kernels
        warm_up(client, make_spec(scene, sources, n, seed, materials, options))
        start_s = time.perf_counter() - t
        before = worker_cpu_seconds(client)
        res = trace(scene, sources, n, seed, materials=materials, options=options, client=client)
        after = worker_cpu_seconds(client)
        t_close = time.perf_counter()
    end = time.perf_counter()
    cpu = {w: after[w] - before[w] for w in after}
    return res, end - t, cpu, start_s, end - t_close


def load(scene_path):
    """(scene, sources, materials, label) of ``--scene`` or the default reference tube."""
    if scene_path:
        from straylight.scene import load_scene

        rs = load_scene(scene_path)
        return rs.scene, rs.sources, rs.materials, scene_path
    from geometry.scenes import reference_scene
    from materials import Lambertian
    from straylight.sources import CollimatedDisk

    scene = reference_scene(tolerance_mm=0.01)
    a = math.radians(30.0)
    sources = [CollimatedDisk([0, 0, 310], [0, 0, -1], [math.sin(a), 0, -math.cos(a)], 60.0)]
    return scene, sources, {scene.parts[0].material: Lambertian(0.05)}, "reference tube, 30 deg"


def one(k, args):
    """``--one K``: one whole run in this (fresh) process; its numbers as JSON on stdout's last line."""
    from straylight.trace import TraceOptions

    scene, sources, materials, _ = load(args.scene)
    res, wall, cpu, start_s, close_s = whole_run(k, scene, sources, materials, args.rays, args.seed, TraceOptions())
    print(json.dumps({"wall_s": wall, "worker_cpu_s": list(cpu.values()), "startup_s": start_s, "close_s": close_s,
                      "casts": int(res.segments + res.shadow_rays), "result": res.to_json_dict()}), flush=True)


def run_fresh(k, args):
    """:func:`one` in a fresh process of this script."""
    import subprocess

    cmd = [sys.executable, __file__, "--one", str(k), "--rays", str(args.rays), "--seed", str(args.seed)]
    if args.scene:
        cmd += ["--scene", args.scene]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", help="scene file (default: the reference tube at 30 deg)")
    ap.add_argument("--rays", type=int, default=8_000_000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--in-process", action="store_true", help="also trace in this process (1 thread)")
    ap.add_argument("--json", default=None)
    ap.add_argument("--one", type=int, default=0, help=argparse.SUPPRESS)  # one K in this process (run_fresh)
    args = ap.parse_args(argv)
    from straylight.trace import TraceOptions, trace

    if args.one:
        return one(args.one, args)
    scene, sources, materials, label = load(args.scene)
    options = TraceOptions()
    tri = np.asarray(scene.triangles_mm, dtype=np.float64)
    print(f"{label}: {len(tri)} triangles, {args.rays:.3g} rays", flush=True)
    raw = raw_rate(tri)
    out = {"scene": label, "triangles": len(tri), "rays": args.rays, "raw_rate_cpu": raw}
    print(f"raw embreex: {raw / 1e6:.2f} M casts/CPU-s", flush=True)
    runs = {}
    for k in (1, 2):
        run = run_fresh(k, args)
        cpu = run["worker_cpu_s"]
        rate = run["casts"] / sum(cpu)
        runs[k] = json.dumps(run["result"], sort_keys=True)  # floats round-trip exactly (repr)
        out[f"wall_s_{k}"] = run["wall_s"]
        out[f"worker_cpu_s_{k}"] = cpu
        out[f"startup_s_{k}"] = run["startup_s"]
        out[f"close_s_{k}"] = run["close_s"]
        out[f"rate_per_process_cpu_{k}"] = rate
        trace_s = run["wall_s"] - run["startup_s"] - run["close_s"]
        print(f"{k} worker process(es): {run['wall_s']:.1f} s whole command = start-up and warm-up "
              f"{run['startup_s']:.1f} s + trace {trace_s:.1f} s + close {run['close_s']:.2f} s; "
              f"trace: worker CPU {', '.join(f'{c:.1f}' for c in cpu)} s, "
              f"{rate / 1e6:.2f} M casts per worker CPU-s = {rate / raw:.0%} of raw", flush=True)
    out["scaling_wall_1_to_2"] = out["wall_s_1"] / out["wall_s_2"]
    same = runs[1] == runs[2]
    out["identical_1_2"] = same
    print(f"scaling 1 -> 2 worker processes, whole command: x{out['scaling_wall_1_to_2']:.2f}; identical numbers: {same}")
    if args.in_process:
        c = time.process_time()
        res = trace(scene, sources, args.rays, args.seed, materials=materials, options=options)
        cpu = time.process_time() - c
        rate = (res.segments + res.shadow_rays) / cpu
        out["rate_in_process_cpu"] = rate
        out["identical_in_process"] = json.dumps(res.to_json_dict(), sort_keys=True) == runs[1]
        print(f"in this process: {rate / 1e6:.2f} M casts/CPU-s = {rate / raw:.0%} of raw; identical: "
              f"{out['identical_in_process']}")
    if args.json:
        import atomicio

        atomicio.write_text(args.json, json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    sys.exit(main())
