"""The cached start-up path: a repeat ``straylight trace`` on a STEP assembly reads the tessellation
cache, imports none of the heavy packages (CAD kernel, plotting, scipy.linalg, dask), and traces the same
numbers as the cold run; numba starts without scipy.linalg (and cffi, for the straylight command) and jitted
linear algebra still works."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

DATA = Path(__file__).resolve().parents[1] / "data" / "cad"
HEAVY = ("OCP", "cadquery", "trimesh", "matplotlib", "pyvista", "dask", "distributed", "pandas", "scipy.linalg")

CHILD = r"""
import json, sys
from straylight.cli.main import main
rc = main(["trace", sys.argv[1], "--rays", "3000", "--seed", "4", "--json", sys.argv[2]])
heavy = sorted(m for m in sys.modules if any(m == h or m.startswith(h + ".") for h in json.loads(sys.argv[3])))
print(json.dumps({"rc": rc, "heavy": heavy}))
"""


def _run(toml, out, cache):
    env = dict(os.environ, STRAYLIGHT_CACHE="on", STRAYLIGHT_CACHE_DIR=str(cache))
    done = subprocess.run([sys.executable, "-c", CHILD, str(toml), str(out), json.dumps(HEAVY)], env=env,
                          capture_output=True, text=True, timeout=600, cwd=Path(__file__).resolve().parents[2])
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_cached_trace_imports_no_heavy_module_and_traces_the_same(tmp_path, cad_bench_scene):
    toml = cad_bench_scene
    cache = tmp_path / "cache"
    cold = _run(toml, tmp_path / "cold.json", cache)
    assert cold["rc"] == 0 and any(m.startswith("OCP") for m in cold["heavy"])  # the cold run did read the STEP
    assert len(list((cache / "tessellation").glob("*.npz"))) == 1
    warm = _run(toml, tmp_path / "warm.json", cache)
    assert warm == {"rc": 0, "heavy": []}
    a, b = (json.loads((tmp_path / f"{k}.json").read_text()) for k in ("cold", "warm"))
    assert a == b and a  # every number of the report, bit for bit


def test_numba_starts_without_scipy_linalg_or_cffi_and_blas_kernels_still_work():
    code = r"""
import sys
from materials.jit_start import for_command_line, start_numba
for_command_line()  # as the straylight command does
start_numba()
assert "scipy.linalg" not in sys.modules, "scipy.linalg imported"
assert "cffi" not in sys.modules, "cffi imported"
import cffi  # unblocked once the target is up
import numpy as np
from numba import njit
a = np.arange(9.0).reshape(3, 3)
dot = njit(lambda x, y: np.dot(x, y))  # BLAS: numba checks again and imports scipy now
assert np.array_equal(dot(a, a), a @ a)
corr = njit(lambda x, y: np.correlate(x, y))  # the one use of numba's start-up BLAS check: its own loop
assert np.allclose(corr(np.arange(5.0), np.ones(3)), np.correlate(np.arange(5.0), np.ones(3)))
print("ok")
"""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600,
                          cwd=Path(__file__).resolve().parents[2])
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr[-2000:]


def test_numba_keeps_cffi_and_its_lock_events_unless_the_command_line_drops_them():
    """A library user's process (a notebook) starts numba with cffi and its LLVM-lock events (their own jitted
    cffi calls work, their compiles are timed); a straylight command that traces drops both
    (materials.jit_start.for_command_line), and a cached kernel still loads and runs."""
    pytest.importorskip("cffi")
    root = Path(__file__).resolve().parents[2]
    code = r"""
import sys
import numpy as np
from straylight.cli.main import _numba_for_command_line
from materials.jit_start import start_numba
if sys.argv[1] == "cli":
    _numba_for_command_line(type("Args", (), {"command": "pst"})())
start_numba()
from llvmlite.binding import ffi
from numba import njit
from numba.core.typing import cffi_utils
lock_events = any(a.__module__ == "numba.core.base" for a, _ in ffi.lib._lock._cblist)
f = njit(lambda x: 2.0 * x)
assert f(np.arange(3.0)).tolist() == [0.0, 2.0, 4.0]
timer = f.get_metadata(f.signatures[0])["timers"].get("llvm_lock", 0.0)  # absent: never timed
print(cffi_utils.SUPPORTED, "cffi" in sys.modules, lock_events, timer > 0)
"""
    for mode, expected in (("library", "True True True True"), ("cli", "False False False False")):
        done = subprocess.run([sys.executable, "-c", code, mode], capture_output=True, text=True, timeout=600,
                              cwd=root)
        assert done.returncode == 0 and done.stdout.strip() == expected, (mode, done.stdout, done.stderr[-2000:])
