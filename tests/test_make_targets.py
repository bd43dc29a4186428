"""Habits that live in files: slow tests run with one make target, which the README
names, and that target selects tests that exist."""
import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _slow_tests() -> list[str]:
    """Tests marked ``@pytest.mark.slow`` (or in a module whose ``pytestmark`` is), found with ast."""
    found = []
    for path in sorted((ROOT / "tests").rglob("test_*.py")):
        tree = ast.parse(path.read_text())
        module_slow = any(isinstance(n, ast.Assign) and any(getattr(t, "id", "") == "pytestmark" for t in n.targets)
                          and "slow" in ast.unparse(n.value) for n in tree.body)
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.name.startswith("test"):
                marks = [ast.unparse(d) for d in node.decorator_list]
                if module_slow or any(m.endswith("mark.slow") for m in marks):
                    found.append(f"{path.relative_to(ROOT)}::{node.name}")
    return found


def test_make_test_slow_runs_the_slow_tests_and_the_readme_says_so():
    makefile = (ROOT / "Makefile").read_text()
    recipe = re.search(r"^test-slow:.*\n\t(.+)$", makefile, re.MULTILINE)
    assert recipe and "pytest" in recipe.group(1) and "-m slow" in recipe.group(1)
    assert "test-slow" in re.search(r"^\.PHONY:(.*)$", makefile, re.MULTILINE).group(1)
    # the default run deselects them (pyproject addopts) and `-m slow` on the command line overrides that
    assert "-m 'not slow'" in (ROOT / "pyproject.toml").read_text()
    assert "make test-slow" in (ROOT / "README.md").read_text()
    assert len(_slow_tests()) >= 5, _slow_tests()
