"""The user guide's "Edge diffraction (HURB)" (docs/guide.md) stays true: its commands run as written (few rays), in a shell, and
the scene they make diffracts where the section says (CONTRACTS §6.5)."""
import json
import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _commands() -> str:
    text = (ROOT / "docs" / "guide.md").read_text()
    start = text.index("### Edge diffraction (HURB)")
    section = text[start:text.index("\n### ", start + 1)]
    block = re.findall(r"```bash\n(.*?)```", section, re.DOTALL)[0]
    return re.sub(r"--rays \d+", "--rays 3000", block)  # the same commands, fewer rays


def test_readme_diffraction_commands_run(tmp_path):
    bindir = Path(sys.executable).parent
    env = dict(os.environ, PATH=f"{bindir}{os.pathsep}{os.environ.get('PATH', '')}",
               PYTHONPATH=f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
    script = "set -e\n" + _commands().replace("--out cam/vis", "--rays 3000 --out cam/vis")
    run = subprocess.run(["bash", "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True, check=False)
    assert run.returncode == 0, run.stderr[-2000:]
    scene = (tmp_path / "cam" / "diffracting.toml").read_text()
    assert scene.count('diffraction = "edges"') == 9  # wall, 7 vanes, end plate; not the detector
    assert "wavelength_nm = 10000.0" in scene
    on = json.loads((tmp_path / "cam" / "on" / "pst.json").read_text())["diffraction"]
    off = json.loads((tmp_path / "cam" / "off" / "pst.json").read_text())["diffraction"]
    vis = json.loads((tmp_path / "cam" / "vis" / "pst.json").read_text())["diffraction"]
    assert on["on"] and on["wavelength_nm"] == 10000.0 and off["on"] is False and vis["wavelength_nm"] == 500.0
