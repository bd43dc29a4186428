"""CONTRACTS §4: every subcommand has --help and exits 0; errors are one line (traceback only with
--debug); the console script is installed; package data a non-editable install needs is declared."""
import argparse
import fnmatch
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from contract_helpers import REPO, assert_one_line_error, run_console


def _subcommand_paths():
    from straylight.cli.main import build_parser

    paths = []

    def walk(parser, prefix):
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    paths.append(prefix + [name])
                    walk(sub, prefix + [name])

    walk(build_parser(), [])
    return paths


def test_contract_subcommands_exist():
    paths = {tuple(p) for p in _subcommand_paths()}
    for p in [("material", "eval"), ("trace",), ("rig", "scan"), ("rig", "diagnose")]:
        assert p in paths, f"straylight {' '.join(p)} is missing"


@pytest.mark.parametrize("path", _subcommand_paths(), ids=lambda p: " ".join(p))
def test_every_subcommand_has_help(cli, path):
    rc, out, err = cli(*path, "--help")
    assert rc == 0, err
    assert out.startswith("usage: straylight " + " ".join(path))


def test_top_level_and_unknown_command(cli):
    rc, out, _ = cli("--help")
    assert rc == 0 and "usage: straylight" in out
    rc, _, err = cli("no-such-command")
    assert rc != 0 and "Traceback" not in err


def test_debug_shows_traceback(cli, tmp_path):
    argv = ["material", "eval", tmp_path / "missing.json", "--theta-i-deg", 10, "--theta-r-deg", 10,
            "--polarization", "s", "--json", tmp_path / "o.json"]
    rc, _, err = cli(*argv)
    assert_one_line_error(rc, err, "missing.json")
    with pytest.raises(ValueError, match="missing.json"):
        from straylight.cli.main import main

        main(["--debug"] + [str(a) for a in argv])


def test_console_script_installed(tmp_path):
    r = run_console(["--help"], cwd=tmp_path)
    assert r.returncode == 0 and "usage: straylight" in r.stdout
    r = run_console(["material", "eval", "nowhere.json", "--theta-i-deg", "10", "--theta-r-deg", "10",
                     "--polarization", "s", "--json", "o.json"], cwd=tmp_path)
    assert_one_line_error(r.returncode, r.stderr, "nowhere.json")


def _package_data_globs():
    cfg = tomllib.loads((REPO / "pyproject.toml").read_text())
    return cfg["tool"]["setuptools"].get("package-data", {})


def test_package_data_declares_every_data_file():
    """A non-editable install must carry presets, measured data and the pyvisa-sim YAMLs: every
    non-Python file tracked inside a package must match a [tool.setuptools.package-data] glob."""
    globs = _package_data_globs()
    tracked = subprocess.run(["git", "ls-files"], cwd=REPO, capture_output=True, text=True).stdout.split()
    if not tracked:
        pytest.skip("not a git checkout")
    missing = []
    for f in tracked:
        top = f.split("/")[0]
        if top not in ("materials", "geometry", "straylight", "rig") or f.endswith(".py") or "__pycache__" in f:
            continue
        # the deepest package (directory with __init__.py) holding the file
        parts = f.split("/")
        pkg_parts = [parts[0]]
        for d in parts[1:-1]:
            if (REPO / Path(*pkg_parts, d) / "__init__.py").exists():
                pkg_parts.append(d)
            else:
                break
        rel = "/".join(parts[len(pkg_parts):])
        pkg = ".".join(pkg_parts)
        ok = any(fnmatch.fnmatch(rel, g) for g in globs.get(pkg, []) + globs.get("*", []))
        # a parent package's glob may also reach down (setuptools matches relative to that package)
        for k in range(1, len(pkg_parts)):
            parent = ".".join(pkg_parts[:k])
            sub_rel = "/".join(parts[k:])
            ok = ok or any(fnmatch.fnmatch(sub_rel, g) for g in globs.get(parent, []))
        if not ok:
            missing.append(f)
    assert not missing, f"not in package-data: {missing}"


def test_runtime_data_directories_present():
    from materials.material import list_presets
    from rig.drivers.visa import SIM_DIR

    assert list_presets()
    assert sorted(p.name for p in SIM_DIR.glob("*.yaml"))


@pytest.mark.slow
def test_fresh_non_editable_install(tmp_path):
    """Fresh clone, fresh venv, non-editable install (dependencies borrowed from this venv)."""
    clone = tmp_path / "c"
    subprocess.run(["git", "clone", "-q", str(REPO), str(clone)], check=True)
    subprocess.run([sys.executable, "-m", "venv", str(tmp_path / "v")], check=True)
    pip = tmp_path / "v" / "bin" / "pip"
    subprocess.run([str(pip), "install", "-q", "--no-deps", str(clone)], check=True, timeout=600)
    site = next((tmp_path / "v" / "lib").glob("python3*/site-packages"))
    assert list((site / "materials" / "library").glob("*.json"))
    assert list((site / "materials" / "data").glob("*.txt"))
    assert list((site / "rig" / "drivers" / "sim").glob("*.yaml"))
    deps = next(Path(sys.prefix, "lib").glob("python3*/site-packages"))
    env = dict(os.environ, PYTHONPATH=str(deps))  # .pth files (the editable install) are not read from PYTHONPATH
    r = subprocess.run([str(tmp_path / "v" / "bin" / "straylight"), "rig", "scan", "--sim", "--sample", "z302_sample_a",
                        "--plan", "paper", "-o", str(tmp_path / "s.csv"), "--help"], capture_output=True, text=True,
                       env=env, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    r = subprocess.run([str(tmp_path / "v" / "bin" / "python"), "-c",
                        "import materials, rig.drivers.visa as v; from materials import load_material;"
                        "load_material('z302_sample_a'); print(materials.__file__, v.SIM_DIR)"],
                       capture_output=True, text=True, env=env, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert str(site) in r.stdout
