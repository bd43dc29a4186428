"""numba caches keyed on the kernel's sources and its helpers' (materials.jit_cache).

numba's own cache checks only the kernel's file; a kernel calling a jitted helper in another file
keeps serving the old machine code after the helper changes (seen during development:
``pairwise_work()`` failed until the cache files were deleted). The end-to-end test below shows
it with plain ``numba.njit`` and shows the project's ``njit`` recompiling."""
from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
from pathlib import Path


from materials import jit_cache

ROOT = Path(__file__).resolve().parents[2]
# self-contained kernels (no helper outside their own function) may use numba.njit directly
# (geometry may not import materials: tests/test_import_arrows.py)
PLAIN_NUMBA_ALLOWED = {"geometry/analytic.py"}

HELPER = '''
{imp}
SCALE = {scale}

@{deco}(cache=True)
def helper(x):
    return x * SCALE + {add}
'''
KERNEL = '''
{imp}
from {pkg}.helper import helper

@{deco}(cache=True)
def kernel(x):
    return helper(x) + 1.0
'''
FLAVOURS = {"probe_pkg": ("from materials.jit_cache import njit", "njit"),  # the project's cache
            "plain_pkg": ("import numba", "numba.njit")}  # numba's own, outside the project's packages
RUN = '''
import json, sys
sys.path.insert(0, {tmp!r})
import materials.jit_cache as jc
jc._PACKAGE_DIRS = jc._PACKAGE_DIRS + ({pkg!r},)
from probe_pkg.kernel import kernel as project_kernel
from plain_pkg.kernel import kernel as plain_kernel
print(json.dumps({{"project": project_kernel(1.0), "plain": plain_kernel(1.0),
                  "project_hits": sum(project_kernel.stats.cache_hits.values()),
                  "plain_hits": sum(plain_kernel.stats.cache_hits.values())}}))
'''


def _write_probe(tmp_path, scale, add):
    for name, (imp, deco) in FLAVOURS.items():
        pkg = tmp_path / name
        pkg.mkdir(exist_ok=True)
        (pkg / "__init__.py").write_text("")
        (pkg / "helper.py").write_text(HELPER.format(imp=imp, deco=deco, scale=scale, add=add))
        (pkg / "kernel.py").write_text(KERNEL.format(imp=imp, deco=deco, pkg=name))
    return tmp_path / "probe_pkg"


def _run(tmp_path, pkg):
    env = dict(os.environ, PYTHONPATH=str(ROOT), NUMBA_CACHE_DIR=str(tmp_path / "numba_cache"))
    env.pop("NUMBA_CACHE_LOCATOR_CLASSES", None)
    out = subprocess.run([sys.executable, "-c", RUN.format(tmp=str(tmp_path), pkg=str(pkg) + os.sep)],
                         env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_a_changed_helper_recompiles_the_cached_kernel(tmp_path):
    pkg = _write_probe(tmp_path, 2.0, 1.0)
    first = _run(tmp_path, pkg)
    assert first["project"] == first["plain"] == 4.0
    again = _run(tmp_path, pkg)  # a warm cache is used (nothing recompiled)
    assert again["project"] == again["plain"] == 4.0 and again["project_hits"] >= 1 and again["plain_hits"] >= 1
    _write_probe(tmp_path, 2.0, 5.0)  # the helper changes; the kernel's file does not
    after = _run(tmp_path, pkg)
    assert after["project"] == 8.0, "the project's cache served a kernel compiled with the old helper"
    # numba's own cache, same files: the stale machine code (the failure this module prevents;
    # drop this line if a numba release starts checking the helpers' files itself)
    assert after["plain"] == 4.0


def test_the_key_covers_helper_sources_and_constants(tmp_path, monkeypatch):
    pkg = _write_probe(tmp_path, 2.0, 1.0)
    monkeypatch.setattr(jit_cache, "_PACKAGE_DIRS", jit_cache._PACKAGE_DIRS + (str(pkg) + os.sep,))
    monkeypatch.syspath_prepend(str(tmp_path))
    import importlib

    def key():
        for m in ("probe_pkg.kernel", "probe_pkg.helper", "probe_pkg"):
            sys.modules.pop(m, None)
        importlib.invalidate_caches()
        kernel = importlib.import_module("probe_pkg.kernel").kernel
        return jit_cache.dependency_key(kernel.py_func), jit_cache.dependencies(kernel.py_func)

    k0, (files, consts) = key()
    assert str(pkg / "helper.py") in files and str(pkg / "kernel.py") in files
    assert consts.get("probe_pkg.helper.SCALE") == "2.0"
    _write_probe(tmp_path, 2.0, 3.5)  # helper source
    k1, _ = key()
    _write_probe(tmp_path, 3.0, 3.5)  # a constant the helper reads
    k2, _ = key()
    assert len({k0, k1, k2}) == 3
    for m in ("probe_pkg.kernel", "probe_pkg.helper", "probe_pkg"):
        sys.modules.pop(m, None)


def test_engine_kernels_depend_on_their_helpers_files_and_constants():
    from straylight.engine import hits

    files, consts = jit_cache.dependencies(hits.hits.py_func)
    names = {Path(f).relative_to(ROOT).as_posix() for f in files}
    assert {"straylight/engine/hits.py", "straylight/engine/vec3.py", "straylight/engine/tally_store.py"} <= names
    assert "straylight.engine.hits.EVENT_SCATTER" in consts and "straylight.engine.hits.ROLE_DETECTOR" in consts


def test_project_kernels_use_the_keyed_cache():
    """Every ``cache=True`` kernel of the project goes through materials.jit_cache.njit."""
    bad = []
    for pkg in ("materials", "geometry", "straylight", "rig"):
        for path in sorted((ROOT / pkg).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            if rel in PLAIN_NUMBA_ALLOWED or rel == "materials/jit_cache.py":
                continue
            tree = ast.parse(path.read_text(encoding="utf-8"))
            for node in ast.walk(tree):
                if isinstance(node, ast.ImportFrom) and node.module == "numba" and any(
                        a.name == "njit" for a in node.names):
                    bad.append(f"{rel}:{node.lineno}: from numba import njit")
                if isinstance(node, ast.Attribute) and node.attr == "njit" and isinstance(node.value, ast.Name) \
                        and node.value.id == "numba":
                    bad.append(f"{rel}:{node.lineno}: numba.njit")
    assert not bad, "use materials.jit_cache.njit for cached kernels:\n" + "\n".join(bad)


RUN_CLONE = '''
import json, sys
sys.path.insert(0, {tmp!r})
import materials.jit_cache as jc
jc._PACKAGE_DIRS = jc._PACKAGE_DIRS + ({pkg!r},)
jc.PACKAGES = jc.PACKAGES + ("probe_pkg",)
from probe_pkg.kernel import kernel
print(json.dumps({{"value": kernel(1.0), "hits": sum(kernel.stats.cache_hits.values())}}))
'''


def test_a_second_clone_finds_the_kernels_the_first_compiled(tmp_path):
    """The cache is keyed by content and package path, not by the checkout's folder (every clone
    paid the first compile again)."""
    cache = tmp_path / "numba_cache"
    results = []
    for clone in ("clone_a", "deeper/clone_b"):
        root = tmp_path / clone
        root.mkdir(parents=True)
        pkg = _write_probe(root, 2.0, 1.0)
        env = dict(os.environ, PYTHONPATH=str(ROOT), NUMBA_CACHE_DIR=str(cache))
        env.pop("NUMBA_CACHE_LOCATOR_CLASSES", None)
        out = subprocess.run([sys.executable, "-c", RUN_CLONE.format(tmp=str(root), pkg=str(pkg) + os.sep)],
                             env=env, capture_output=True, text=True, timeout=300)
        assert out.returncode == 0, out.stderr[-3000:]
        results.append(json.loads(out.stdout.strip().splitlines()[-1]))
    assert results[0] == {"value": 4.0, "hits": 0}  # compiled in the first clone
    assert results[1]["value"] == 4.0 and results[1]["hits"] >= 1  # served from the cache in the second
    assert [p.name for p in cache.iterdir()] == ["probe_pkg"]  # one folder, named by the package path


def test_cache_folders_are_named_by_package_path():
    a = jit_cache.cache_subpath("/home/a/straylight/straylight/engine/hits.py")
    b = jit_cache.cache_subpath("/tmp/x/y/clone/straylight/engine/hits.py")
    assert a == b == "straylight_engine"
    assert jit_cache.project_relative("/srv/checkout/materials/lambertian.py") == "materials/lambertian.py"
