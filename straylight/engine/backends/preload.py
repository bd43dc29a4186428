"""Imported once by the fork server that starts a local cluster's worker processes
(:func:`straylight.engine.backends.dask.local_cluster` with ``processes=True``): the engine's modules are
imported and its compiled kernels loaded from numba's on-disk cache here, so that every worker
forked from the server starts with them (a spawned worker spent ~1-1.5 s of CPU on this itself, all
workers at once, before its first ray).

The kernels are loaded by tracing one chunk of a two-triangle scene on the numpy
:class:`straylight.intersect.reference.ReferenceIntersector`: embree (and its thread pool) is
not started in the server, which must stay free of threads to fork safely. (The server starts with
the environment dask's nanny sets for its workers, e.g. one OpenBLAS thread: ``distributed.nanny.
pre-spawn-environ`` is put into this process's environment before the first worker starts.)
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from geometry.mesh import Part, Scene
from materials import Lambertian
from straylight.engine.options import EstimatorOptions, TraceOptions
from straylight.engine.plan import build_tables, resolve
from straylight.engine.runtime import runtime
from straylight.engine.spec import make_spec
from straylight.engine.strategies.base import TableTools
from straylight.engine.walk import run_batch
from straylight.intersect.reference import ReferenceIntersector
from straylight.sources import CollimatedDisk


def load_kernels() -> None:
    """Trace one chunk of a tiny scene (a black square facing a detector square) in this process:
    the compiled kernels of the usual options (NEE with and without first-vertex sampling, plain walk)
    are loaded from numba's cache. The tables are built by the strategies the plan runs, as
    :func:`straylight.trace.trace` builds them."""
    rt = runtime()  # the server's Runtime, started: numba's target without scipy.linalg, the allocator tuned

    square = np.array([[-10, -10, 0], [10, -10, 0], [10, 10, 0], [-10, 10, 0]], dtype=np.float64)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    wall = Part("wall", square + [0, 0, 5], faces[:, ::-1], material="black")
    detector = Part("detector", square, faces, role="detector")
    scene = Scene((wall, detector))
    source = CollimatedDisk(np.array([0.0, 0.0, 4.0]), np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, 1.0]), 5.0)
    for nee, vertex in ((True, True), (True, False), (False, False)):  # the CLI's default first: NEE, vertex sampling
        options = TraceOptions(estimator=EstimatorOptions(nee=nee, first_vertex_sampling=vertex), batch_rays=1000)
        spec = make_spec(scene, [source], 100, 0, {"black": Lambertian(0.5)}, options)
        isect = ReferenceIntersector(spec.triangles_mm)
        # the plan of the workers' traces (on embree); here numpy's intersector stands in for embree in the
        # tables (built as trace() builds them, through the strategies) and the walk, which runs that plan
        plan = resolve(options, spec)
        spec = build_tables(spec, plan, TableTools(runtime=rt, intersector=isect, run_batch=run_batch), cache=False)
        run_batch(replace(spec, strategies_on=plan.on), 0, 1, isect)


try:
    load_kernels()
except Exception:  # noqa: BLE001 - a head start only: the workers load what they need themselves
    pass
