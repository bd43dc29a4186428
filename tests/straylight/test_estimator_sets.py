"""The public estimator sets are the default one; the history sets live in benchmarks/ and are
registered there (straylight.analyses.estimators.register_estimator_set)."""
import subprocess
import sys
from pathlib import Path

import pytest

from straylight.analyses.estimators import register_estimator_set
from straylight.engine.options import EstimatorOptions

ROOT = Path(__file__).resolve().parents[2]


def test_only_the_default_lens_and_ghosts_sets_are_public():
    """In a fresh interpreter (another test of this process may have registered the benchmarks' sets): the default,
    the lens set (the default with scatter points lit through a lens, straylight.engine.lens_vertex) and the ghosts
    set (the default with specular NEE through a singlet's two-reflection ghosts): choices for users, documented in
    ``pst --help``; the benchmarks' history sets only when registered."""
    out = subprocess.run([sys.executable, "-c", "from straylight.analyses.estimators import ESTIMATOR_SETS, "
                          "estimator_options\nprint(list(ESTIMATOR_SETS))\n"
                          "try:\n    estimator_options('baseline')\nexcept ValueError as e:\n    print(e)"],
                         capture_output=True, text=True, cwd=ROOT, check=True).stdout.splitlines()
    assert out[0] == "['default', 'lens', 'ghosts']"
    assert "unknown estimator set 'baseline'" in out[1]


def test_the_default_set_cannot_be_replaced_and_a_set_must_be_options():
    with pytest.raises(ValueError, match="cannot be replaced"):
        register_estimator_set("default", EstimatorOptions())
    with pytest.raises(TypeError, match="expected EstimatorOptions"):
        register_estimator_set("mine", {"nee": True})


def test_benchmarks_register_the_history_sets_for_the_command():
    """``python benchmarks/estimator_sets.py pst --help`` is the straylight command with the history sets."""
    out = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "estimator_sets.py"), "pst", "--help"],
                         capture_output=True, text=True, check=True).stdout
    choices = out[out.index("--estimators"):].split("}")[0]
    for name in ("default", "baseline", "split", "lobes", "roulette", "first_lobe"):
        assert name in choices, out
