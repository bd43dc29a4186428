"""The import arrows of STYLE §1 hold: atomicio <- materials <- geometry (names only) <- straylight <- rig.

Walks every module with ``ast`` and fails on a forbidden import.
"""
import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
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
            if package == "straylight" and "cli" in path.relative_to(ROOT / package).parts:
                continue  # the CLI sits above every package and imports rig lazily
            for name, line, col in _imports(path):
                if name in forbidden:
                    bad.append(f"{path.relative_to(ROOT)}:{line}: imports {name}")
    assert not bad, "\n".join(bad)


def test_import_straylight_does_not_pull_bluesky():
    import subprocess
    import sys

    code = "import sys, straylight, straylight.cli.main as m; m.build_parser(); print('bluesky' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
