"""The import arrows of STYLE §1 hold: atomicio <- materials <- geometry (names only) <- straylight <- rig,
with no cycles between files, straylight.engine below the rest of straylight, and the ``straylight`` command
finds ``rig`` through its entry point.

Walks every module with ``ast`` (imports inside functions included: a lazy import is still an
arrow) and fails on a forbidden import or a cycle.
"""
import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("atomicio", "materials", "geometry", "straylight", "rig")
FORBIDDEN = {
    # atomicio (the one atomic file writer) sits below every package: all may import it
    "atomicio": {"materials", "geometry", "straylight", "rig", "numpy", "bluesky", "ophyd"},
    "materials": {"geometry", "straylight", "rig", "trimesh", "embreex", "cadquery", "pyvista", "bluesky", "ophyd"},
    "geometry": {"materials", "straylight", "rig", "embreex", "bluesky", "ophyd"},
    "straylight": {"rig", "bluesky", "ophyd"},
    "rig": set(),
}


def _imports(path):
    tree = ast.parse(path.read_text(), filename=str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name.split(".")[0], node.lineno, node.col_offset
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            yield node.module.split(".")[0], node.lineno, node.col_offset


def test_no_forbidden_imports():
    bad = []
    for package, forbidden in FORBIDDEN.items():
        for path in (ROOT / package).rglob("*.py"):
            for name, line, col in _imports(path):
                if name in forbidden:
                    bad.append(f"{path.relative_to(ROOT)}:{line}: imports {name}")
    assert not bad, "\n".join(bad)


# ------------------------------------------------------------------ cycles between files


def module_files(root=ROOT, packages=PACKAGES) -> dict:
    """{dotted module name: file} of every module of ``packages`` (a package is its __init__.py)."""
    out = {}
    for package in packages:
        for path in (Path(root) / package).rglob("*.py"):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = path
    return out


def import_graph(modules: dict) -> dict:
    """{module: set of modules it imports} (within ``modules``; an import of a name is an arrow to
    the most specific module that exists: ``from a.b import c`` -> ``a.b.c`` if it is a module,
    else ``a.b``). Relative imports are resolved; imports inside functions count too."""

    def known(name):
        while name and name not in modules:
            name = name.rpartition(".")[0]
        return name or None

    graph = {}
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        targets = set()
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Import):
                targets.update(known(a.name) for a in node.names)
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                    origin = ".".join(base + ([node.module] if node.module else []))
                else:
                    origin = node.module
                for a in node.names:
                    full = f"{origin}.{a.name}"
                    targets.add(full if full in modules else known(origin))
        targets.discard(None)
        targets.discard(name)
        graph[name] = targets
    return graph


def cycles(graph: dict) -> list:
    """Strongly connected components of more than one module (Tarjan), each sorted."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(limit, 10 * len(graph) + 100))
    try:
        for v in sorted(graph):
            if v not in index:
                visit(v)
    finally:
        sys.setrecursionlimit(limit)
    return found


def test_no_two_files_import_each_other():
    found = cycles(import_graph(module_files()))
    assert not found, "import cycles between files (lazy imports count):\n" + "\n".join(" <-> ".join(c) for c in found)


def test_cycle_finder_sees_a_lazy_cycle(tmp_path):
    """The finder is not vacuous: a cycle closed by an import inside a function, through a package
    __init__ and a relative import, is found; a one-way chain is not."""
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from pkg.sub import thing\n")
    (pkg / "sub" / "__init__.py").write_text("from .b import thing\n")
    (pkg / "sub" / "b.py").write_text("def thing():\n    import pkg.a\n")
    (pkg / "c.py").write_text("import pkg.a\n")
    found = cycles(import_graph(module_files(tmp_path, ("pkg",))))
    assert found == [["pkg.a", "pkg.sub", "pkg.sub.b"]]


# ------------------------------------------------------------------ the engine sits below the rest of straylight

# the modules of straylight the engine stands on (random streams, path records, detectors, sources,
# intersectors, run checks): they and the engine import nothing of straylight above them (trace,
# analyses, cli, design, thermal, checkpoints, progress, ...). The engine's backends (dask, fork server,
# thread pool) live in straylight/engine/backends (the dask code used to sit above the engine).
ENGINE_FLOOR = ("straylight.rng", "straylight.pcg64", "straylight.paths", "straylight.detectors", "straylight.sources",
                "straylight.budget", "straylight.run_checks", "straylight.polarization", "straylight.intersect",
                "straylight.disk_sampling")


def _in(name: str, roots) -> bool:
    return any(name == r or name.startswith(r + ".") for r in roots)


def test_the_engine_imports_nothing_of_straylight_above_it():
    graph = import_graph(module_files())
    below = ("straylight.engine", *ENGINE_FLOOR)
    bad = [f"{module} imports {target}" for module, targets in sorted(graph.items()) if _in(module, below)
           for target in sorted(targets) if _in(target, ("straylight",)) and not _in(target, below)]
    assert not bad, "the engine (and what it stands on) imports from above it:\n" + "\n".join(bad)
    assert "straylight.engine.backends.dask" in graph and "straylight.distribute" not in graph


# ------------------------------------------------------------------ the command's entry points


def test_import_straylight_does_not_pull_bluesky():
    code = "import sys, straylight, straylight.cli.main as m; m.build_parser(); print('bluesky' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_straylight_help_lists_rig_through_its_entry_point():
    from importlib.metadata import entry_points

    eps = {ep.name: ep.value for ep in entry_points(group="straylight.commands")}
    assert eps.get("rig") == "rig.cli:add_parser", f"installed straylight.commands entry points: {eps}"
    out = subprocess.run([sys.executable, "-m", "straylight.cli.main", "--help"], capture_output=True, text=True,
                         check=True)
    listed = [line.split()[0] for line in out.stdout.splitlines() if line.startswith("    ") and line.split()]
    assert "rig" in listed, out.stdout


# ------------------------------------------------------------------ layers of straylight: arrows point down

# straylight's top-level modules and subpackages, lowest layer first. An import may point within a
# layer or down, never up; and no two units import each other (through any chain). The arrows that
# once ran back up (the study tables under thermal, the disk sampler inside the engine, the path
# label inside the path report) are now in the floor: straylight.frames, straylight.disk_sampling,
# straylight.paths.sequence_label.
STRAYLIGHT_LAYERS = (
    ("floor", ("straylight", "straylight.pcg64", "straylight.rng", "straylight.paths", "straylight.run_checks",
               "straylight.progress", "straylight.polarization", "straylight.frames", "straylight.compile_notice",
               "straylight.checkpoints", "straylight.optics", "straylight.disk_sampling", "straylight.sources",
               "straylight.intersect", "straylight.detectors", "straylight.budget")),
    ("engine", ("straylight.engine", "straylight.execution", "straylight.stop_rule")),
    ("runs", ("straylight.trace", "straylight.scene", "straylight.thermal")),
    ("displays", ("straylight.viz", "straylight.view3d", "straylight.viewer")),
    ("analyses", ("straylight.analyses",)),
    ("front", ("straylight.api", "straylight.design", "straylight.cli")),
)


def unit_of(module: str) -> str:
    """The layer unit of a module: ``straylight.<x>`` for anything under straylight.<x>, else the package."""
    parts = module.split(".")
    return ".".join(parts[:2]) if parts[0] == "straylight" else parts[0]


def unit_graph(graph: dict) -> dict:
    """{unit: units it imports} from the file graph (arrows inside a unit dropped)."""
    out: dict = {}
    for module, targets in graph.items():
        a = unit_of(module)
        out.setdefault(a, set())
        for t in targets:
            b = unit_of(t)
            out.setdefault(b, set())
            if a != b:
                out[a].add(b)
    return out


def upward_arrows(units: dict, layers) -> list:
    """'a -> b' for every arrow from a unit to one of a higher layer (units of no layer are left out)."""
    level = {u: i for i, (_, members) in enumerate(layers) for u in members}
    return [f"{a} ({layers[level[a]][0]}) -> {b} ({layers[level[b]][0]})" for a, targets in sorted(units.items())
            for b in sorted(targets) if a in level and b in level and level[b] > level[a]]


def test_every_straylight_unit_has_a_layer():
    units = unit_graph(import_graph(module_files()))
    placed = {u for _, members in STRAYLIGHT_LAYERS for u in members}
    missing = sorted(u for u in units if u.startswith("straylight") and u not in placed)
    assert not missing, f"place these in STRAYLIGHT_LAYERS (tests/test_import_arrows.py): {missing}"


def test_straylight_imports_point_down_the_layers_without_cycles():
    units = unit_graph(import_graph(module_files()))
    up = upward_arrows(units, STRAYLIGHT_LAYERS)
    assert up == [], "imports that run up the layers:\n" + "\n".join(up)
    found = cycles({u: t for u, t in units.items() if u.startswith("straylight")})
    assert found == [], "units of straylight that import each other:\n" + "\n".join(" <-> ".join(c) for c in found)
    # the three arrows that ran back up are gone
    graph = import_graph(module_files())
    assert "straylight.analyses.tables" not in graph["straylight.thermal.run"] | graph["straylight.thermal.exchange"]
    assert not any(t.startswith("straylight.engine") for t in graph["straylight.detectors"])
    assert not any(t.startswith("straylight.analyses") for t in graph["straylight.view3d"])


def test_layer_check_sees_an_upward_arrow():
    """Not vacuous: an arrow from the floor to the engine is reported, a downward one is not."""
    layers = (("floor", ("straylight.rng",)), ("engine", ("straylight.engine",)))
    units = unit_graph({"straylight.rng": {"straylight.engine.walk"}, "straylight.engine.walk": {"straylight.rng"}})
    assert upward_arrows(units, layers) == ["straylight.rng (floor) -> straylight.engine (engine)"]
    assert cycles(units) == [["straylight.engine", "straylight.rng"]]
