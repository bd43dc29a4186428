"""Start-up (time to the first traced rays) and memory on big CAD assemblies, cold and cached.

    python benchmarks/startup.py [--sizes 0.36M 1M 5M] [--out DIR] [--rays 20000]

For each size, K copies of the hooked-vane tube (geometry.parts.assembly, 354,546 triangles at
0.005 mm) are written as ONE named STEP assembly (OCP's XDE writer: a "tube" sub-assembly of 46
named products, placed K times side by side, as a CAD tool writes repeated parts) and a scene.toml
that loads it with ``split = "solids"`` (one part per solid, the detectors by per-solid
overrides): K = 1, 3, 14 for about 0.36M, 1.06M, 5.0M triangles. The reader meshes a product once
and places its instances (``geometry.io._Instances``), so the cold time of the big scenes is
mostly one tube's meshing plus reading and placing; the cached runs read the whole mesh back.
Each run is a fresh process (so its peak RSS is its own):

- cold: empty tessellation cache (read STEP, tessellate, measure chord errors, write the cache);
- cached: the same command again (the cache entry is read instead).

Python's own bytecode cache is warm in the cached run, as for an installed package (pip compiles
the .pyc files): ``PYTHONDONTWRITEBYTECODE`` is dropped from the children's environment unless
``--no-bytecode`` (with it, every run compiles the project's ~75 modules from source: ~0.1-0.2 s).

Reported per run (wall seconds counted from the process's start, interpreter start-up included, on
Linux): ``import_s`` when the tracer is imported (numpy, numba, embreex, straylight: the same for
any scene), ``load_s`` when the scene is loaded (``straylight.scene.load_scene``: geometry, checks,
materials, sources, numba's start), ``bvh_s`` when the engine's scene is ready
(``make_spec`` + ``compiled_scene``: triangle tables, embree geometry and BVH), ``first_rays_s``
after a 1000-ray trace (which loads the compiled kernels from numba's cache first); the CPU seconds
of each stage (``cpu_*``, all threads; a busy shared machine inflates them less than wall times),
the time of the same 1000 rays again (so kernels ~ first - again), the heavy modules imported (none
on the cached path), peak RSS (VmHWM, Linux) after the first rays, and after a trace of
``--rays`` and of 10x that many rays: memory stays flat in ray count (the tracer works in
fixed-size batches). The ratio cold/cached is measured within one run. The machine is shared.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

TOLERANCE_MM = 0.005
SIZES = {"0.36M": 1, "1M": 3, "5M": 14}  # copies of the tube
PITCH_MM = 200.0  # copies side by side along x (flange diameter 135 mm)
HEAVY_MODULES = ("OCP", "cadquery", "trimesh", "scipy.linalg", "matplotlib", "pyvista", "dask", "distributed", "pandas")


def _rss_mb() -> float:
    """Peak RSS of this process: VmHWM (Linux; of this program's memory since exec), else ru_maxrss (which on
    Linux keeps the high-water mark of the parent at fork: the benchmark's parent, having written the STEP
    with OpenCascade, is ~580 MB, and every child reported at least that before)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _process_age_s():
    """Seconds since this process started (Linux /proc, 10 ms ticks: interpreter start-up included), or None."""
    try:
        with open("/proc/self/stat") as f:
            start_ticks = int(f.read().rsplit(")", 1)[1].split()[19])
        with open("/proc/uptime") as f:
            uptime = float(f.read().split()[0])
        return max(uptime - start_ticks / os.sysconf("SC_CLK_TCK"), 0.0)
    except (OSError, ValueError, IndexError):
        return None


def child(toml: str, rays: int) -> dict:
    """One measurement in this (fresh) process: wall seconds from the process's start (interpreter start-up
    included, Linux) to the end of each stage (``*_s``), and the CPU seconds of each stage (``cpu_*_s``)."""
    start = _process_age_s()
    t0 = time.perf_counter() - (start if start is not None else 0.0)  # the process's start on this clock
    marks = {}

    def mark(name):  # process_time: CPU seconds of this process since it started (all threads)
        marks[name] = (time.perf_counter() - t0, time.process_time())

    import warnings

    import embreex  # noqa: F401 - the imports any scene pays (tracer, embree, numba), timed apart
    import numpy as np

    import straylight.trace  # noqa: F401
    from straylight.engine.runtime import runtime
    from straylight.engine.spec import make_spec
    from straylight.scene import load_scene

    mark("import")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rs = load_scene(toml)
    mark("load")
    n_tri = int(sum(p.n_triangles for p in rs.scene.parts))
    spec = make_spec(rs.scene, rs.sources, 1000, 1, materials=rs.materials)
    comp = runtime().scene(spec)  # kept for the trace below (same geometry: same per-process scene)
    comp.isect.first_triangle(np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]))  # embree builds its BVH on first use
    mark("bvh")
    rs.trace(1000, seed=1)  # loads the compiled kernels from numba's cache, then traces
    mark("first")
    rss_first = _rss_mb()
    t = time.perf_counter()
    rs.trace(1000, seed=1)  # the same again, kernels loaded: what the first trace spent on rays alone
    t_again = time.perf_counter() - t
    t = time.perf_counter()
    rs.trace(rays, seed=2)
    t_rays = time.perf_counter() - t
    rss_rays = _rss_mb()
    rs.trace(10 * rays, seed=3)
    rss_10x = _rss_mb()
    cached = any("cache" in p.meta for p in rs.scene.parts)
    heavy = sorted(m for m in HEAVY_MODULES if m in sys.modules)
    (w_imp, c_imp), (w_load, c_load), (w_bvh, c_bvh), (w_first, c_first) = (
        marks[k] for k in ("import", "load", "bvh", "first"))
    return {"triangles": n_tri, "parts": len(rs.scene.parts), "from_cache": cached,
            "import_s": w_imp, "load_s": w_load, "bvh_s": w_bvh, "first_rays_s": w_first,
            "cpu_import_s": c_imp, "cpu_load_s": c_load - c_imp, "cpu_bvh_s": c_bvh - c_load,
            "cpu_kernels_and_rays_s": c_first - c_bvh, "cpu_first_rays_s": c_first,
            "trace_1000_again_s": t_again, "heavy_modules": heavy,
            "rss_first_mb": rss_first, "rays": rays, "trace_s": t_rays,
            "rss_after_rays_mb": rss_rays, "rss_after_10x_rays_mb": rss_10x}


def write_tubes_step(path: Path, copies: int) -> list[str]:
    """STEP with ``copies`` placed instances of the tube sub-assembly; returns the first copy's part names."""
    from OCP.gp import gp_Trsf, gp_Vec
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.STEPCAFControl import STEPCAFControl_Writer
    from OCP.STEPControl import STEPControl_AsIs
    from OCP.TCollection import TCollection_ExtendedString
    from OCP.TDataStd import TDataStd_Name
    from OCP.TDocStd import TDocStd_Document
    from OCP.TopLoc import TopLoc_Location
    from OCP.XCAFDoc import XCAFDoc_DocumentTool

    from geometry.parts.assembly import DEFAULT, hooked_tube_assembly

    parts = hooked_tube_assembly(DEFAULT)
    doc = TDocStd_Document(TCollection_ExtendedString("XmlOcaf"))
    tool = XCAFDoc_DocumentTool.ShapeTool_s(doc.Main())
    top, tube = tool.NewShape(), tool.NewShape()
    TDataStd_Name.Set_s(top, TCollection_ExtendedString("bench"))
    TDataStd_Name.Set_s(tube, TCollection_ExtendedString("tube"))
    for name, part in parts.items():
        label = tool.AddShape(part.shape.wrapped, False)
        TDataStd_Name.Set_s(label, TCollection_ExtendedString(name))
        tool.AddComponent(tube, label, TopLoc_Location())
    for k in range(copies):
        t = gp_Trsf()
        t.SetTranslation(gp_Vec(k * PITCH_MM, 0.0, 0.0))
        tool.AddComponent(top, tube, TopLoc_Location(t))
    tool.UpdateAssemblies()
    writer = STEPCAFControl_Writer()
    writer.SetNameMode(True)
    writer.Transfer(doc, STEPControl_AsIs)
    if writer.Write(str(path)) != IFSelect_RetDone:
        raise RuntimeError(f"cannot write {path}")
    return list(parts)


def build(size: str, directory: Path) -> Path:
    """tubes_<size>.step + scene_<size>.toml (split = "solids", every copy's detector a detector)."""
    import tomli_w

    from geometry.cad import unique_names
    from geometry.parts.assembly import DEFAULT, collimated_source

    directory.mkdir(parents=True, exist_ok=True)
    copies = SIZES[size]
    step = directory / f"tubes_{size}.step"
    names = write_tubes_step(step, copies)
    solids = unique_names(names * copies)  # the reader's names: detector, detector_2, ...
    detectors = [n for n in solids if n == "detector" or n.startswith("detector_")]
    source = collimated_source(DEFAULT)
    source["center_mm"][0] = (copies - 1) * PITCH_MM / 2
    source["radius_mm"] = float(np.hypot((copies - 1) * PITCH_MM / 2, 0.0) + DEFAULT.flange_radius_mm)
    doc = {"part": [{"name": "tubes", "mesh": step.name, "split": "solids", "tolerance_mm": TOLERANCE_MM,
                     "material": "z302_sample_b", "role": "surface",
                     "solids": {d: {"role": "detector"} for d in detectors}}],
           "source": [source]}
    toml = directory / f"scene_{size}.toml"
    toml.write_text(tomli_w.dumps(doc))
    return toml


def run(toml: Path, rays: int, cache_dir: Path, bytecode: bool = True) -> dict:
    env = dict(os.environ, STRAYLIGHT_CACHE="on", STRAYLIGHT_CACHE_DIR=str(cache_dir))
    if bytecode:  # Python's own .pyc cache warm, as for an installed package (pip compiles it)
        env.pop("PYTHONDONTWRITEBYTECODE", None)
    out = subprocess.run([sys.executable, __file__, "--child", str(toml), "--rays", str(rays)], env=env,
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def run_cli(toml: Path, cache_dir: Path, bytecode: bool = True, rays: int = 1000) -> dict:
    """``straylight trace SCENE --rays 1000 --json OUT`` as a user runs it: the whole command, wall and CPU."""
    env = dict(os.environ, STRAYLIGHT_CACHE="on", STRAYLIGHT_CACHE_DIR=str(cache_dir))
    if bytecode:
        env.pop("PYTHONDONTWRITEBYTECODE", None)
    out = toml.parent / "startup_cli.json"
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    subprocess.run([sys.executable, "-c", "import sys; from straylight.cli.main import main; sys.exit(main())",
                    "trace", str(toml), "--rays", str(rays), "--json", str(out)], env=env, capture_output=True,
                   text=True, check=True)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"cli_rays": rays, "cli_wall_s": wall, "cli_cpu_s": cpu}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="+", default=list(SIZES), choices=list(SIZES))
    parser.add_argument("--rays", type=int, default=20000)
    parser.add_argument("--out", default=None, help="folder for the STEP/scene files and startup.json")
    parser.add_argument("--no-bytecode", action="store_true",
                        help="keep PYTHONDONTWRITEBYTECODE if set (every run compiles the project's modules)")
    parser.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        print(json.dumps(child(args.child, args.rays)))
        return 0
    out = Path(args.out or tempfile.mkdtemp(prefix="straylight_startup_"))
    rows = []
    for size in args.sizes:
        toml = build(size, out)
        cache_dir = out / f"cache_{size}"
        for label in ("cold", "cached"):
            result = run(toml, args.rays, cache_dir, bytecode=not args.no_bytecode)
            result.update(size=size, run=label, tolerance_mm=TOLERANCE_MM, copies=SIZES[size])
            rows.append(result)
            print(f"{size:>6} {label:<6} {result['triangles']:>9,d} tri  wall from start: imports "
                  f"{result['import_s']:5.2f} s, loaded {result['load_s']:6.2f} s, BVH {result['bvh_s']:6.2f} s, "
                  f"first rays {result['first_rays_s']:6.2f} s  |  CPU: imports {result['cpu_import_s']:5.2f}, "
                  f"load {result['cpu_load_s']:6.2f}, embree {result['cpu_bvh_s']:5.2f}, kernels+1000 rays "
                  f"{result['cpu_kernels_and_rays_s']:5.2f} (1000 rays again: {result['trace_1000_again_s']:.2f} s "
                  f"wall), total {result['cpu_first_rays_s']:6.2f} s", flush=True)
            print(f"{'':>13} peak RSS {result['rss_first_mb']:7.0f} MB, after {result['rays']:,d} rays "
                  f"{result['rss_after_rays_mb']:7.0f} MB, after {10 * result['rays']:,d} "
                  f"{result['rss_after_10x_rays_mb']:7.0f} MB; heavy modules imported: "
                  f"{', '.join(result['heavy_modules']) or 'none'}", flush=True)
        cli = run_cli(toml, cache_dir, bytecode=not args.no_bytecode)
        rows[-1].update(cli)
        print(f"{size:>6} cached `straylight trace --rays {cli['cli_rays']}` (whole command): "
              f"{cli['cli_wall_s']:.2f} s wall, {cli['cli_cpu_s']:.2f} s CPU", flush=True)
        cold, cached = rows[-2], rows[-1]
        print(f"{size:>6} cold/cached time to first rays: x{cold['first_rays_s'] / cached['first_rays_s']:.1f}")
    import atomicio

    atomicio.write_json(out / "startup.json", {"rows": rows, "note": "shared 2-core machine"})
    print(f"results: {out / 'startup.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
