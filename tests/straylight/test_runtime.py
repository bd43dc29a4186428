"""One Runtime per process: it owns the compiled scene, the kept sampling tables, the
batch thread pools and the start (numba's target, the allocator); a dask worker plugin sets it up
on workers; no import hook and no write to a private attribute of dask."""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np

import straylight.engine.runtime as runtime_module
from geometry.mesh import Part, Scene
from materials import Lambertian
from straylight.engine.runtime import Runtime, runtime
from straylight.execution import Execution
from straylight.sources import CollimatedDisk
from straylight.trace import EstimatorOptions, TraceOptions, trace

ROOT = Path(__file__).resolve().parents[2]
SQUARE = np.array([[-10, -10, 0], [10, -10, 0], [10, 10, 0], [-10, 10, 0]], dtype=np.float64)
FACES = np.array([[0, 1, 2], [0, 2, 3]])


def _box(z_wall_mm):
    """A black square ``z_wall_mm`` above a detector square, lit from just below the wall."""
    wall = Part("wall", SQUARE + [0, 0, z_wall_mm], FACES[:, ::-1], material="black")
    scene = Scene((wall, Part("detector", SQUARE, FACES, role="detector")))
    source = CollimatedDisk(np.array([0.0, 0.0, z_wall_mm - 1.0]), np.array([0.0, 0.0, 1.0]),
                            np.array([0.0, 0.0, 1.0]), 5.0)
    return scene, [source]


def test_one_runtime_per_process_builds_the_scene_once_and_keeps_its_pool(monkeypatch):
    built = []
    real = runtime_module.CompiledScene
    monkeypatch.setattr(runtime_module, "CompiledScene", lambda *a: built.append(1) or real(*a))
    scene, sources = _box(5.25)  # a geometry no other test traces: its scene is not kept yet
    options = TraceOptions(estimator=EstimatorOptions(first_vertex_sampling=False), batch_rays=1000)
    rt = runtime()
    a = trace(scene, sources, 4000, seed=3, materials={"black": Lambertian(0.5)}, options=options,
              execution=Execution(threads=2))
    b = trace(scene, sources, 4000, seed=3, materials={"black": Lambertian(0.5)}, options=options)
    assert runtime() is rt and rt.started
    assert len(built) == 1, "the second trace of the same geometry rebuilt its scene"
    assert rt.pool(2) is rt.pool(2)
    # threads or not, the same numbers (the pool changes where batches run, not what they sum)
    assert a.detectors["detector"].power_w == b.detectors["detector"].power_w > 0


def test_a_fresh_runtime_closes_what_it_owns():
    rt = Runtime(tune_allocator=False)
    assert not rt.started
    pool = rt.pool(1)
    assert pool.submit(lambda: 7).result() == 7
    rt.close()
    assert rt.pool(1) is not pool and not rt.scene_tokens()


START = r"""
import os, sys
hooks = list(sys.meta_path)
from straylight.engine.runtime import runtime
rt = runtime()
assert list(sys.meta_path) == hooks, ("meta_path changed", sys.meta_path, hooks)
assert "scipy.linalg" not in sys.modules, "scipy.linalg imported (or left blocked) by the start"
pid = os.fork()
if pid == 0:  # a forked child gets its own Runtime (threads and scenes do not survive a fork)
    os._exit(0 if runtime() is not rt and runtime().started else 1)
assert os.waitpid(pid, 0)[1] == 0, "the forked child reused its parent's Runtime"
print(rt.started, rt.allocator_tuned)
"""


def test_the_start_installs_no_import_hook_and_the_allocator_tuning_can_be_turned_off():
    env = {"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin", "STRAYLIGHT_CACHE": "off"}
    on = subprocess.run([sys.executable, "-c", START], capture_output=True, text=True, env=env, timeout=120)
    assert on.returncode == 0, on.stderr
    off = subprocess.run([sys.executable, "-c", START], capture_output=True, text=True, timeout=120,
                         env={**env, "STRAYLIGHT_TUNE_ALLOCATOR": "0"})
    assert off.returncode == 0, off.stderr
    assert off.stdout.split() == ["True", "False"]
    if sys.platform.startswith("linux"):
        assert on.stdout.split() == ["True", "True"]


def test_the_worker_plugin_sets_up_the_runtime_on_a_local_cluster_worker():
    from dask.distributed import Client

    from straylight.engine.backends.dask import local_cluster, register_runtime
    from straylight.engine.backends.worker_plugin import PLUGIN_NAME

    with local_cluster(1) as cluster, Client(cluster) as client:
        register_runtime(client)
        register_runtime(client)  # idempotent
        (address,) = client.scheduler_info()["workers"]
        plugins = client.run(lambda dask_worker: sorted(dask_worker.plugins))
        assert PLUGIN_NAME in plugins[address]
        # in-process worker: the Runtime is this process's, and the plugin's setup recorded the worker in it
        assert address in runtime().workers
        assert client.run(lambda: id(runtime()))[address] == id(runtime())
    assert address not in runtime().workers  # teardown when the worker closed


def test_no_private_attribute_of_dask_is_written_and_no_import_hook_is_installed():
    private = re.compile(r"\b(distributed|dask)(\.\w+)*\._\w+\s*=(?!=)|setattr\(\s*(distributed|dask)\b")
    hook = re.compile(r"\bsys\.meta_path\b|\bsys\.path_hooks\b")
    bad = []
    for package in ("atomicio", "materials", "geometry", "straylight", "rig", "benchmarks"):
        for path in sorted((ROOT / package).rglob("*.py")):
            for k, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
                if private.search(line) or hook.search(line):
                    bad.append(f"{path.relative_to(ROOT)}:{k}: {line.strip()}")
    assert not bad, "\n".join(bad)
    assert private.search("distributed.utils._forkserver_preload_set = True")  # the write this replaced
    assert hook.search("sys.meta_path.insert(0, finder)")
