"""Comments and docstrings say what and why, not which issue: no "issue 27" / "issue #39" in the
code, the tests, the benchmarks or the examples (docs/engine.md, "Habits")."""
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = ("atomicio", "materials", "geometry", "straylight", "rig", "tests", "benchmarks", "examples")
ISSUE = re.compile(r"\b[Ii]ssues? #?\d+|\(#\d+\)")


def issue_mentions(text: str) -> list[str]:
    return [m.group(0) for m in ISSUE.finditer(text)]


def test_no_issue_numbers_in_the_code():
    found = []
    for folder in FOLDERS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            if path == Path(__file__).resolve():  # its own examples
                continue
            for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
                if issue_mentions(line):
                    found.append(f"{path.relative_to(ROOT)}:{n}: {line.strip()[:100]}")
    assert not found, "say what, not which issue:\n" + "\n".join(found)


def test_the_pattern_finds_issue_numbers_and_nothing_else():
    assert issue_mentions("a fix (issue 27, item 3)") == ["issue 27"]
    assert issue_mentions("Issue #39: a spike") == ["Issue #39"]
    assert issue_mentions("see (#17)") == ["(#17)"]
    assert issue_mentions('{"sample": "Z302 #2"}; colour "#c44e52"; tissue 3') == []
