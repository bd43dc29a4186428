"""Worker-process scaling on dask, each run timed whole, K = 1 and 2 alternately.

    .venv/bin/python benchmarks/worker_scaling.py [--scene SCENE.toml] [--rays N] [--seed S] [--repeat R] [--json OUT]

For K = 1 and 2: a LocalCluster of K worker processes with one thread each (bound to 127.0.0.1,
as ``straylight.engine.backends.dask.local_cluster(K, processes=True)``), one trace of ``--rays`` rays,
cluster closed: the wall time of all of it (start-up, scene shipped to and built in each worker,
compiled kernels loaded from numba's cache, tracing, shutdown), counted from after the scene is
loaded (which any command does first; not counted, but printed). Also the per-process rate: ray
casts (segments + shadow rays) per CPU second of each worker process, against raw embreex's rate
measured in this run on the same scene (``EmbreeScene.run`` on incoherent rays, 1 thread),
counted from after the workers' start-up (imports, scene built, kernels loaded: timed apart), and
optionally (``--in-process``) the same trace in this process. Numbers must be identical for every
run and in-process (printed).

Each run is a fresh Python process of this script (``--one K``): the worker processes are forked
from a server that imports the engine and loads the kernels once (``straylight.engine.backends.fork_server``),
which a second cluster in the same process would reuse; a fresh process gives every run its full
start-up. As ``straylight trace SCENE --workers K --processes`` does, the server is launched
before the scene is loaded and loads (~1.5 s of one core) while the scene loads; the part of it
that the load covers is not in the counted time, as it is not in a user's (``--late-fork-server``:
launched by the cluster, after the load, as before). The phases are printed: the load (not
counted), start-up = cluster up (``cluster``: waits for the fork server, starts scheduler and
workers) + ``warm-up`` (spec made, sent to every worker, scene built there, one chunk traced:
kernels loaded), then trace and close; and the ``warm start-up`` of a second cluster started
afterwards in the same process (fork server running: cluster up + warm-up).

Drift: a shared or virtual machine's speed drifts (here +-15 % between runs minutes apart), so a
K = 1 run and a K = 2 run taken at different moments give a noisy ratio. The runs therefore
alternate, K = 1, 2, 1, 2, ... (``--repeat R`` pairs, default 3), and two ratios are printed:

- ``median pair ratio``: the median over the R adjacent pairs (K = 1 run i, K = 2 run i, taken
  one after the other) of wall(K = 1) / wall(K = 2): the headline number (the scaling line);
- ``best-to-best ratio``: the fastest K = 1 run's wall time over the fastest K = 2 run's.

Raw embreex is measured before the first pair and after every pair (R + 1 times); its spread is
printed (how much the machine's speed moved during the run), and each run's per-process rate is
given against the mean of the raw rates measured just before and just after its pair.

Default scene: the reference tube (``geometry.scenes.reference_scene(0.01)``, 15k triangles, 30 deg).
The wall-time ratio is meaningful only when two cores are free; the CPU-time rates are not
disturbed by neighbours.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np


class RawRate:
    """Raw embreex first-hit rate per CPU second on incoherent rays inside the scene's bounding box
    (the scene and rays built once; :meth:`measure` may be called again to follow the drift)."""

    def __init__(self, triangles_mm, n=1_000_000):
        from straylight.intersect import EmbreeIntersector

        self.isect = EmbreeIntersector(triangles_mm)
        rng = np.random.default_rng(0)
        lo, hi = triangles_mm.reshape(-1, 3).min(axis=0), triangles_mm.reshape(-1, 3).max(axis=0)
        self.o = (lo + (hi - lo) * (0.25 + 0.5 * rng.random((n, 3)))).astype(np.float32)
        d = rng.normal(size=(n, 3))
        self.d = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
        self.isect._scene.run(self.o[:10000], self.d[:10000])
        self.rates = []

    def measure(self):
        """Best of 3 casts of the n rays, casts per CPU second (also appended to ``rates``)."""
        best = 0.0
        for _ in range(3):
            c = time.process_time()
            self.isect._scene.run(self.o, self.d)
            best = max(best, len(self.o) / (time.process_time() - c))
        self.rates.append(best)
        return best


def whole_run(k, scene, sources, materials, n, seed, options):
    """Start K worker processes, trace, close: (result, wall s, worker CPU s of the trace itself
    (after start-up: imports, scene shipped and built, kernels loaded), start-up wall s, close wall
    s, {phase: wall s}, the spec)."""
    from dask.distributed import Client

    from straylight.engine.backends.dask import local_cluster, warm_up, worker_cpu_seconds
    from straylight.execution import Execution
    from straylight.trace import make_spec, trace

    t0 = t = time.perf_counter()
    phases = {}
    with local_cluster(k, processes=True) as cluster, Client(cluster) as client:
        phases["cluster"] = time.perf_counter() - t
        t = time.perf_counter()
        # what the first trace's tasks would do anyway: each worker builds the scene, loads the kernels
        spec = make_spec(scene, sources, n, seed, materials, options)
        warm_up(client, spec)
        phases["warm-up"] = time.perf_counter() - t
        start_s = time.perf_counter() - t0
        before = worker_cpu_seconds(client)
        res = trace(scene, sources, n, seed, materials=materials, options=options, execution=Execution(client=client))
        after = worker_cpu_seconds(client)
        t_close = time.perf_counter()
    end = time.perf_counter()
    cpu = {w: after[w] - before[w] for w in after}
    return res, end - t0, cpu, start_s, end - t_close, phases, spec


def warm_startup(k, spec):
    """Start-up of a second cluster in this process (the fork server already running, this process
    warm): cluster up and warm-up, wall s (then closed)."""
    from dask.distributed import Client

    from straylight.engine.backends.dask import local_cluster, warm_up

    t = time.perf_counter()
    with local_cluster(k, processes=True) as cluster, Client(cluster) as client:
        warm_up(client, spec)
        return time.perf_counter() - t


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
    """``--one K``: one whole run in this (fresh) process; its numbers as JSON on stdout's last line.
    The worker processes' fork server is launched first (``straylight.engine.backends.fork_server.start``, as
    ``straylight trace --workers K --processes`` does) and loads while the scene loads, unless
    ``--late-fork-server`` (the cluster launches it); the clock starts after the scene is loaded."""
    t0 = time.perf_counter()
    if not args.late_fork_server:
        from straylight.engine.backends import fork_server

        fork_server.start()
    from straylight.trace import TraceOptions

    scene, sources, materials, _ = load(args.scene)
    load_s = time.perf_counter() - t0
    res, wall, cpu, start_s, close_s, phases, spec = whole_run(k, scene, sources, materials, args.rays, args.seed,
                                                               TraceOptions())
    phases = {"(load, not counted)": load_s, **phases}
    warm_s = warm_startup(k, spec)
    print(json.dumps({"wall_s": wall, "worker_cpu_s": list(cpu.values()), "startup_s": start_s, "close_s": close_s,
                      "startup_phases_s": phases, "warm_startup_s": warm_s,
                      "casts": int(res.segments + res.shadow_rays), "result": res.to_json_dict()}), flush=True)


def run_fresh(k, args):
    """:func:`one` in a fresh process of this script."""
    import subprocess

    cmd = [sys.executable, __file__, "--one", str(k), "--rays", str(args.rays), "--seed", str(args.seed)]
    if args.late_fork_server:
        cmd.append("--late-fork-server")
    if args.scene:
        cmd += ["--scene", args.scene]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def _median(xs):
    xs = sorted(xs)
    n = len(xs)
    return xs[n // 2] if n % 2 else 0.5 * (xs[n // 2 - 1] + xs[n // 2])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", help="scene file (default: the reference tube at 30 deg)")
    ap.add_argument("--rays", type=int, default=8_000_000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--repeat", type=int, default=3, help="pairs of runs K = 1, K = 2, alternating (default 3)")
    ap.add_argument("--in-process", action="store_true", help="also trace in this process (1 thread)")
    ap.add_argument("--late-fork-server", action="store_true",
                    help="launch the workers' fork server with the cluster, after the scene is loaded (before "
                         "straylight.engine.backends.fork_server.start was called first: for before/after comparisons)")
    ap.add_argument("--json", default=None)
    ap.add_argument("--one", type=int, default=0, help=argparse.SUPPRESS)  # one K in this process (run_fresh)
    args = ap.parse_args(argv)
    from straylight.trace import TraceOptions, trace

    if args.one:
        return one(args.one, args)
    if args.repeat < 1:
        ap.error(f"--repeat must be >= 1, got {args.repeat}")
    scene, sources, materials, label = load(args.scene)
    options = TraceOptions()
    tri = np.asarray(scene.triangles_mm, dtype=np.float64)
    print(f"{label}: {len(tri)} triangles, {args.rays:.3g} rays, {args.repeat} pair(s) of runs K = 1, 2 alternating",
          flush=True)
    raw = RawRate(tri)
    print(f"raw embreex: {raw.measure() / 1e6:.2f} M casts/CPU-s (before pair 1)", flush=True)
    out = {"scene": label, "triangles": len(tri), "rays": args.rays, "repeat": args.repeat, "runs": []}
    results = set()
    for i in range(args.repeat):
        pair = {}
        for k in (1, 2):
            run = run_fresh(k, args)
            results.add(json.dumps(run["result"], sort_keys=True))  # floats round-trip exactly (repr)
            run.pop("result")
            pair[k] = run
        after = raw.measure()
        around = 0.5 * (raw.rates[-2] + after)  # raw rate just before and just after this pair
        for k in (1, 2):
            run = pair[k]
            cpu = run["worker_cpu_s"]
            rate = run["casts"] / sum(cpu)
            trace_s = run["wall_s"] - run["startup_s"] - run["close_s"]
            run.update(k=k, pair=i + 1, rate_per_process_cpu=rate, raw_rate_cpu=around, trace_s=trace_s)
            out["runs"].append(run)
            phases = "".join(f"; {name} {s:.2f}" for name, s in run["startup_phases_s"].items())
            print(f"pair {i + 1}: {k} worker process(es): {run['wall_s']:.1f} s whole command = start-up and warm-up "
                  f"{run['startup_s']:.1f} s + trace {trace_s:.1f} s + close {run['close_s']:.2f} s; "
                  f"trace: worker CPU {', '.join(f'{c:.1f}' for c in cpu)} s, "
                  f"{rate / 1e6:.2f} M casts per worker CPU-s = {rate / around:.0%} of raw"
                  + f" [start-up s: {phases[2:]}; warm start-up {run['warm_startup_s']:.2f}]", flush=True)
        ratio = pair[1]["wall_s"] / pair[2]["wall_s"]
        print(f"pair {i + 1}: K=1 / K=2 whole command x{ratio:.2f}; raw embreex after it "
              f"{after / 1e6:.2f} M casts/CPU-s", flush=True)
    runs = out["runs"]
    walls = {k: [r["wall_s"] for r in runs if r["k"] == k] for k in (1, 2)}
    pair_ratios = [a / b for a, b in zip(walls[1], walls[2])]
    out["pair_ratios"] = pair_ratios
    out["scaling_wall_1_to_2"] = _median(pair_ratios)  # the headline: median adjacent-pair ratio
    out["scaling_wall_best_1_to_best_2"] = min(walls[1]) / min(walls[2])
    out["raw_rates_cpu"] = raw.rates
    for k in (1, 2):  # medians per K (the keys of a single run before --repeat)
        mine = [r for r in runs if r["k"] == k]
        starts = [r["startup_s"] for r in mine]
        out[f"wall_s_{k}"] = _median(walls[k])
        out[f"startup_s_{k}"] = _median([r["startup_s"] for r in mine])
        out[f"close_s_{k}"] = _median([r["close_s"] for r in mine])
        out[f"rate_per_process_cpu_{k}"] = _median([r["rate_per_process_cpu"] for r in mine])
        out[f"rate_of_raw_{k}"] = _median([r["rate_per_process_cpu"] / r["raw_rate_cpu"] for r in mine])
        out[f"warm_startup_s_{k}"] = _median([r["warm_startup_s"] for r in mine])
        wall, start, rate, of_raw = (out[f"{name}_{k}"] for name in ("wall_s", "startup_s", "rate_per_process_cpu",
                                                                     "rate_of_raw"))
        print(f"{k} worker process(es), median of {len(mine)}: {wall:.1f} s whole command "
              f"(runs {', '.join(f'{w:.1f}' for w in walls[k])} s), start-up and warm-up {start:.2f} s "
              f"(runs {', '.join(f'{s:.2f}' for s in starts)} s; warm {out[f'warm_startup_s_{k}']:.2f} s); "
              f"{rate / 1e6:.2f} M casts per worker CPU-s = {of_raw:.0%} of raw", flush=True)
    lo, hi = min(raw.rates), max(raw.rates)
    print(f"raw embreex, {len(raw.rates)} measurements (before pair 1 and after each pair): "
          f"{', '.join(f'{r / 1e6:.2f}' for r in raw.rates)} M casts/CPU-s; spread {lo / 1e6:.2f}-{hi / 1e6:.2f} "
          f"(max/min x{hi / lo:.2f}: the machine's speed drift during this run)")
    same = len(results) == 1
    out["identical_1_2"] = same
    print(f"scaling 1 -> 2 worker processes, whole command: x{out['scaling_wall_1_to_2']:.2f} (median pair ratio: "
          f"median over {len(pair_ratios)} adjacent K=1/K=2 pairs of {', '.join(f'x{r:.2f}' for r in pair_ratios)}); "
          f"best-to-best ratio (fastest K=1 / fastest K=2): x{out['scaling_wall_best_1_to_best_2']:.2f}; "
          f"identical numbers: {same}")
    if args.in_process:
        c = time.process_time()
        res = trace(scene, sources, args.rays, args.seed, materials=materials, options=options)
        cpu = time.process_time() - c
        rate = (res.segments + res.shadow_rays) / cpu
        out["rate_in_process_cpu"] = rate
        out["identical_in_process"] = json.dumps(res.to_json_dict(), sort_keys=True) in results and same
        print(f"in this process: {rate / 1e6:.2f} M casts/CPU-s = {rate / raw.rates[-1]:.0%} of raw (the last raw "
              f"measurement); identical: {out['identical_in_process']}")
    if args.json:
        import atomicio

        atomicio.write_text(args.json, json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    sys.exit(main())
