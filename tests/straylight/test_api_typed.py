"""``Instrument.pst`` takes its precision and execution as typed objects
(``precision=Precision(...)``, ``execution=Execution(...)``) and returns a PstResult; the short form
``target_rel_error=`` (with its caps) makes the same Precision and the same numbers."""
import typing

import numpy as np
import pytest

import straylight.api as sl
from straylight.analyses.types import PstResult


@pytest.fixture(scope="module")
def inst():
    return sl.load(builtin="tube")


def test_typed_precision_and_execution_give_the_short_forms_numbers(inst):
    typed = inst.pst([10.0], seed=2, precision=sl.Precision(0.2, max_rays=8_000),
                     execution=sl.Execution(threads=2))
    short = inst.pst([10.0], seed=2, target_rel_error=0.2, max_rays=8_000)
    assert isinstance(typed, PstResult)
    np.testing.assert_array_equal(typed.pst, short.pst)
    np.testing.assert_array_equal(typed.pst_stderr, short.pst_stderr)


def test_precision_given_twice_or_untyped_is_refused(inst):
    with pytest.raises(ValueError, match="precision=Precision.*or target_rel_error, not both"):
        inst.pst([10.0], precision=sl.Precision(0.1), target_rel_error=0.1)
    with pytest.raises(TypeError, match="precision must be a straylight.api.Precision"):
        inst.pst([10.0], precision=0.1)


def test_the_analyses_return_types_are_annotated():
    for name in ("pst", "paths", "critical", "view3d"):
        hints = typing.get_type_hints(getattr(sl.Instrument, name), vars(sl) | _lazy_types())
        assert "return" in hints, name
    hints = typing.get_type_hints(sl.Instrument.pst, vars(sl) | _lazy_types())
    assert hints["return"] is PstResult
    assert hints["precision"] == sl.Precision | None and hints["execution"] == sl.Execution | None


def _lazy_types():
    from straylight.analyses.critical import CriticalReport
    from straylight.analyses.paths_report import PathReport

    return {"CriticalReport": CriticalReport, "PathReport": PathReport}
