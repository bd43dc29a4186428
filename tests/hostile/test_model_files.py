"""``--model`` refuses a file that is not Python (main 13a6b5b: "'NoneType' object has no
attribute 'loader'") and a model that calls sys.exit() (main: straylight ended with exit 0 and no
report), each in one line naming the file."""
from __future__ import annotations

import pytest

from straylight.analyses.model import ModelError, design_scene
from straylight.cli.main import main


def _study(tmp_path, model: str) -> int:
    return main(["study", "--model", model, "--rays", "1000", "--out", str(tmp_path / "report")])


def test_not_a_python_file_refused(tmp_path, capsys):
    text = tmp_path / "passwd"
    text.write_text("root:x:0:0:root:/root:/bin/bash\n")
    assert _study(tmp_path, f"{text}:build") == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "a model is a Python file ending in .py" in err and "NoneType" not in err


@pytest.mark.parametrize("code", [0, 3])
def test_model_exiting_at_import_refused(tmp_path, capsys, code):
    model = tmp_path / "m.py"
    model.write_text(f"import sys\nsys.exit({code})\ndef build(**kw):\n    return {{}}\n")
    assert _study(tmp_path, f"{model}:build") == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and f"called sys.exit({code})" in err
    assert not (tmp_path / "report" / "report.md").exists()


def test_model_exiting_in_build_refused(tmp_path):
    model = tmp_path / "m.py"
    model.write_text("import sys\ndef build(**kw):\n    sys.exit(0)\n")
    with pytest.raises(ModelError, match=r"build\(\) called sys.exit\(0\)"):
        design_scene(f"{model}:build", {}, tmp_path / "scene")
