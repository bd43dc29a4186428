"""Imports inside functions only for heavy libraries, in straylight/engine and materials.

A lazy import is allowed when it brings in a heavy library (:data:`HEAVY`: compilers, CAD,
plotting, clusters, scipy), directly or through a project module that imports one at module level
or that compiles kernels when imported (found here by walking the module-level imports and
``@njit`` decorators of the project with ``ast``): start-up of the
command line and of worker processes must not pay for them. Everything else, the project's own
light modules and the standard library, is imported at the top of the file, where a reader and the
import-arrow test (tests/test_import_arrows.py) see it. Ruff's PLC0415 flags every lazy import
and has no allow-list, hence this test.
"""
from __future__ import annotations

import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CHECKED = ("straylight/engine", "materials")
PROJECT = ("atomicio", "materials", "geometry", "straylight", "rig")
HEAVY = {"numba", "llvmlite", "scipy", "embreex", "cadquery", "OCP", "pyvista", "vtk", "matplotlib", "dask",
         "distributed", "trimesh", "manifold3d", "rtree", "miepython", "bokeh", "tqdm", "pandas", "selenium",
         "bluesky", "ophyd", "pyvisa", "cryptography"}


def _module_file(name: str) -> Path | None:
    base = ROOT.joinpath(*name.split("."))
    for p in (base.with_suffix(".py"), base / "__init__.py"):
        if p.exists():
            return p
    return None


def _resolve(node: ast.ImportFrom, module: str) -> str:
    if node.level == 0:
        return node.module or ""
    parts = module.split(".")[:-node.level]
    return ".".join(parts + ([node.module] if node.module else []))


def _imported(node, module: str) -> list[str]:
    """Full names a (module-level or lazy) import statement loads."""
    if isinstance(node, ast.Import):
        return [a.name for a in node.names]
    base = _resolve(node, module)
    out = [base]
    for a in node.names:  # `from pkg import submodule`
        if _module_file(f"{base}.{a.name}") is not None:
            out.append(f"{base}.{a.name}")
    return out


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _top_level_imports(tree: ast.Module) -> list:
    """Import statements executed when the module is imported (not inside functions or TYPE_CHECKING)."""
    out = []

    def visit(body):
        for node in body:
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                out.append(node)
            elif isinstance(node, ast.If) and "TYPE_CHECKING" in ast.dump(node.test):
                continue
            elif isinstance(node, (ast.If, ast.Try, ast.With)):
                visit(node.body)
                for h in getattr(node, "handlers", []):
                    visit(h.body)
                visit(getattr(node, "orelse", []))
                visit(getattr(node, "finalbody", []))

    visit(tree.body)
    return out


_HEAVY_MEMO: dict = {}


def _compiles_at_import(tree: ast.Module) -> bool:
    """A top-level function decorated with ``njit(...)``: importing the module starts numba."""
    for node in tree.body:
        if isinstance(node, ast.FunctionDef):
            for d in node.decorator_list:
                f = d.func if isinstance(d, ast.Call) else d
                if (isinstance(f, ast.Name) and f.id in ("njit", "jit")) or (
                        isinstance(f, ast.Attribute) and f.attr in ("njit", "jit")):
                    return True
    return False


def is_heavy(name: str) -> bool:
    """Whether importing ``name`` loads a heavy library (directly or through project modules)."""
    if name in _HEAVY_MEMO:
        return _HEAVY_MEMO[name]
    top = name.split(".")[0]
    if top in HEAVY or top not in PROJECT:
        return top in HEAVY
    _HEAVY_MEMO[name] = False  # while in progress: a cycle adds nothing
    path = _module_file(name)
    if path is None:
        return False
    module = _module_name(path)
    tree = ast.parse(path.read_text(encoding="utf-8"))
    parents = [".".join(name.split(".")[:k]) for k in range(1, name.count(".") + 1)]  # packages' __init__
    deps = [d for node in _top_level_imports(tree) for d in _imported(node, module)] + parents
    _HEAVY_MEMO[name] = _compiles_at_import(tree) or any(is_heavy(d) for d in deps if d != name)
    return _HEAVY_MEMO[name]


def lazy_imports(path: Path) -> list[tuple[int, str]]:
    module = _module_name(path)
    tree = ast.parse(path.read_text(encoding="utf-8"))
    out = []
    for fn in ast.walk(tree):
        if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            for node in ast.walk(fn):
                if isinstance(node, (ast.Import, ast.ImportFrom)):
                    out += [(node.lineno, name) for name in _imported(node, module)[:1]]
    return out


def test_lazy_imports_only_for_heavy_libraries():
    bad = []
    for folder in CHECKED:
        for path in sorted((ROOT / folder).rglob("*.py")):
            for lineno, name in lazy_imports(path):
                if not is_heavy(name):
                    bad.append(f"{path.relative_to(ROOT)}:{lineno}: import {name} inside a function "
                               "(light: move it to the top of the file)")
    assert not bad, "\n".join(bad)


def test_the_rule_tells_heavy_from_light():
    assert is_heavy("scipy.optimize") and is_heavy("materials.fit")  # scipy at its top
    assert is_heavy("straylight.engine.vec3")  # compiles kernels when imported
    assert not is_heavy("materials.base") and not is_heavy("dataclasses")
    assert sys.modules.get(__name__) is not None


def test_building_the_command_line_parser_loads_no_heavy_library():
    """``straylight --help``, a mistyped flag and every command's start pay only for argparse: the parser's
    help texts and choices come from light modules (straylight.engine.hurb's METHOD, not .diffraction, which
    starts numba; straylight.paths' ANCESTRY, not analyses.paths_report, which imports the tracer)."""
    import subprocess

    code = ("import sys; from straylight.cli.main import build_parser; build_parser(); "
            "print(' '.join(sorted(sys.modules)))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                            cwd=ROOT).stdout.split()
    heavy = sorted({m.split(".")[0] for m in loaded} & HEAVY)
    project = {"straylight.engine.diffraction", "straylight.engine.edge_index", "straylight.analyses.paths_report",
               "straylight.trace", "straylight.engine.backends.dask"} & set(loaded)
    assert not heavy and not project, f"building the parser imported {heavy + sorted(project)}"


def test_an_in_process_run_loads_no_cluster_code():
    """A trace on this process (every ``straylight pst`` or ``trace`` without ``--workers``/``--scheduler``)
    imports the dask backend only when a cluster is asked for (straylight.cli.cluster_args.cluster_client,
    straylight.engine.scheduling.run_batches, straylight.trace.trace): its module brings asyncio, sockets and the fork server, ~0.02 CPU s of each
    command's start."""
    import subprocess

    code = ("import argparse, sys, straylight.cli.main, straylight.cli.pst, straylight.api, straylight.trace, "
            "straylight.analyses.pst, straylight.engine.scheduling\n"
            "from straylight.cli.cluster_args import execution\n"
            "with execution(argparse.Namespace(workers=None, scheduler=None), in_process_below=2) as ex:\n"
            "    assert ex.client is None\n"
            "with execution(argparse.Namespace(workers=1, scheduler=None), in_process_below=2) as ex:\n"
            "    assert ex.client is None\n"
            "print(' '.join(sorted(sys.modules)))")
    loaded = set(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                                cwd=ROOT).stdout.split())
    cluster = {"straylight.engine.backends.dask", "straylight.engine.backends.fork_server", "asyncio",
               "dask", "distributed"} & loaded
    assert not cluster, f"an in-process run imported {sorted(cluster)}"
