"""dask distribution: the same seed gives the same numbers in-process and on 1 or 2 workers."""
import math

import pytest

from engine_helpers import baffled_tube_scene
from materials import Lambertian
from straylight.sources import CollimatedDisk
from straylight.trace import OutputOptions, TraceOptions, trace
from straylight.execution import Execution


def _same_ray_log(res, local):
    assert len(local.ray_log) > 5000 and set(local.ray_log.ray.tolist()) == set(range(5000))
    for field in ("ray", "event", "origin_mm", "direction", "end_mm", "tri", "kind", "weight_w", "detector"):
        assert (getattr(res.ray_log, field) == getattr(local.ray_log, field)).all(), field


@pytest.fixture(scope="module")
def setup():
    scene = baffled_tube_scene()
    src = CollimatedDisk([0, 0, 310], [0, 0, -1], [math.sin(0.35), 0, -math.cos(0.35)], 60.0)
    mats = {"black": Lambertian(0.05)}  # importable by worker processes (test helpers are not)
    # the ray log spans two batches: it comes back from workers and threads as from this process
    opts = TraceOptions(output=OutputOptions(record_paths=True, ray_log=5000), batch_rays=3000)
    local = trace(scene, src, 9000, seed=5, materials=mats, options=opts)
    return scene, src, mats, opts, local


@pytest.mark.parametrize("workers", [1, 2])
def test_same_numbers_on_any_worker_count(setup, workers):
    scene, src, mats, opts, local = setup
    res = trace(scene, src, 9000, seed=5, materials=mats, options=opts, execution=Execution(workers=workers))
    assert local.detectors["detector"].power_w > 0
    assert res.to_json_dict() == local.to_json_dict()
    assert (res.paths.key == local.paths.key).all()
    _same_ray_log(res, local)


def test_same_numbers_on_a_thread_pool(setup):
    """threads=2: batches run concurrently in one process (embree and the kernels release the GIL)."""
    scene, src, mats, opts, local = setup
    res = trace(scene, src, 9000, seed=5, materials=mats, options=opts, execution=Execution(threads=2))
    assert local.detectors["detector"].power_w > 0
    assert res.to_json_dict() == local.to_json_dict()
    assert (res.paths.key == local.paths.key).all()
    _same_ray_log(res, local)


@pytest.mark.parametrize("n_rays,batch,slots", [(400_000, 50_000, 2), (2_000_000, 50_000, 2), (9000, 3000, 2),
                                               (123_456, 20_000, 3), (1000, 50_000, 4)])
def test_task_plan_covers_every_batch_once_in_order_with_shrinking_tasks(n_rays, batch, slots):
    from straylight.engine.backends.dask import TASK_BATCHES, task_plan
    from straylight.rng import batches

    ranges = batches(n_rays, batch)
    tasks = task_plan(ranges, slots)
    assert [r for t in tasks for r in t] == ranges  # whole batches, each once, in order
    sizes = [len(t) for t in tasks]
    assert max(sizes) <= TASK_BATCHES
    assert sizes == sorted(sizes, reverse=True)  # guided: tasks shrink toward the end
    assert sizes[-1] == 1  # the tail is single batches
    if len(ranges) >= 4 * slots:
        assert len(tasks) < len(ranges)  # fewer tasks than batches


def test_the_same_trace_repeated_on_one_client(setup):
    """Back-to-back traces of one spec on a reused client (as a benchmark or a PST sweep does): each
    must complete with the same numbers (a content-hashed scatter key used to be dropped under the
    next trace's tasks)."""
    from dask.distributed import Client

    from straylight.engine.backends.dask import local_cluster

    scene, src, mats, opts, local = setup
    with local_cluster(2) as cluster, Client(cluster) as client:
        for _ in range(4):
            res = trace(scene, src, 9000, seed=5, materials=mats, options=opts, execution=Execution(client=client))
            assert res.to_json_dict() == local.to_json_dict()


def test_pooled_plan_keeps_every_batch_in_order_in_runs_the_pool_can_share():
    from straylight.engine.backends.dask import pooled_plan

    ranges = [(k, k + 1) for k in range(37)]
    for pool in (1, 2, 3):
        tasks = pooled_plan(ranges, pool)
        assert [r for t in tasks for r in t] == ranges
        assert all(len(t) % pool == 0 for t in tasks[:-1])
        assert len(tasks[0]) <= 8 * pool
    assert pooled_plan([], 2) == []
