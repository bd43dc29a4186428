"""What TLS costs a local cluster of worker processes: ``local_cluster(2, processes=True)``
with its per-run TLS key (``straylight.engine.backends.dask.run_security``) against the same cluster on plain
TCP, alternating, each starting the cluster and tracing the golden tube; prints each run and the
medians (the first run of each kind is a warm-up). The numbers must be identical.

    python benchmarks/cluster_tls.py [--pairs 6] [--rays 200000]
"""
from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

TUBE = Path(__file__).resolve().parents[1] / "tests" / "data" / "engine_golden" / "tube.toml"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=6)
    ap.add_argument("--rays", type=int, default=200_000)
    args = ap.parse_args()
    from dask.distributed import Client

    import straylight.engine.backends.dask as dist
    from straylight.scene import load_scene
    from straylight.execution import Execution
    from straylight.trace import trace

    rs = load_scene(TUBE)
    tls_class = dist._process_cluster_class

    def plain_class():
        base = tls_class()

        class Plain(base):
            def __init__(self, *a, **k):
                k.pop("protocol", None)
                k.pop("security", None)
                super().__init__(*a, **k)

        return Plain

    t = time.perf_counter()
    dist.run_security()
    print(f"per-run key and certificate: {time.perf_counter() - t:.3f} s (first call, with imports)")
    rows = []
    try:
        for _ in range(args.pairs):
            for mode in ("tls", "plain"):
                dist._process_cluster_class = tls_class if mode == "tls" else plain_class
                t0 = time.perf_counter()
                with dist.local_cluster(2, processes=True) as cluster, Client(cluster) as client:
                    t1 = time.perf_counter()
                    res = trace(rs.scene, rs.sources, args.rays, 1, materials=rs.materials,
                                execution=Execution(client=client))
                    t2 = time.perf_counter()
                t3 = time.perf_counter()
                assert cluster.scheduler_address.startswith("tls://" if mode == "tls" else "tcp://")
                power = res.detectors["detector"].power_w
                rows.append((mode, t1 - t0, t2 - t1, t3 - t0, power))
                print(f"{mode:5s} start {t1 - t0:.2f} s  trace {t2 - t1:.2f} s  total {t3 - t0:.2f} s  detector {power!r}",
                      flush=True)
    finally:
        dist._process_cluster_class = tls_class
    assert len({r[4] for r in rows}) == 1, "TLS changed the numbers"
    for mode in ("tls", "plain"):
        r = [x for x in rows if x[0] == mode][1:]
        print(f"{mode:5s} median start {statistics.median(x[1] for x in r):.2f} s, trace "
              f"{statistics.median(x[2] for x in r):.2f} s, total {statistics.median(x[3] for x in r):.2f} s")


if __name__ == "__main__":
    main()
