"""The ``straylight`` command keeps the BLAS libraries to one thread (straylight.cli.main.single_threaded_blas):
set before numpy loads its BLAS, never over a count the environment names."""
import os
import subprocess
import sys

import numpy

from straylight.cli.main import BLAS_THREAD_VARIABLES, single_threaded_blas


def _clear(monkeypatch):
    for name in BLAS_THREAD_VARIABLES:
        monkeypatch.delenv(name, raising=False)


def test_one_blas_thread_unless_the_environment_names_a_count(monkeypatch):
    _clear(monkeypatch)
    monkeypatch.setenv("MKL_NUM_THREADS", "4")
    monkeypatch.delitem(sys.modules, "numpy")  # as at the command's start: numpy not loaded yet
    single_threaded_blas()
    assert os.environ["OPENBLAS_NUM_THREADS"] == "1"
    assert os.environ["BLIS_NUM_THREADS"] == "1"
    assert os.environ["MKL_NUM_THREADS"] == "4"  # the user's own count stays


def test_nothing_is_set_once_numpy_has_loaded_its_blas(monkeypatch):
    _clear(monkeypatch)
    monkeypatch.setitem(sys.modules, "numpy", numpy)
    single_threaded_blas()
    assert not any(name in os.environ for name in BLAS_THREAD_VARIABLES)


def test_the_command_sets_it_before_its_parser_and_numpy_load():
    env = {k: v for k, v in os.environ.items() if k not in BLAS_THREAD_VARIABLES}
    code = ("import os, sys, straylight.cli.main as m\n"
            "m._main = lambda argv=None: print(os.environ.get('OPENBLAS_NUM_THREADS'), 'numpy' in sys.modules) or 0\n"
            "m.main([])\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True).stdout
    assert out.split() == ["1", "False"]
