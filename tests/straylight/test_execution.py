"""``Execution``: where a trace runs, in one object (issue 23); the numbers never depend on it."""
from __future__ import annotations

import pytest

from straylight.execution import Execution
from straylight.trace import TraceError, TraceOptions, trace
from test_engine_contract import CONTRACT_SCENES, _source


def _run(**kw):
    case = CONTRACT_SCENES["brdf_scatter"]()
    return trace(case.scene, _source(), 6000, seed=3, materials=case.materials,
                 options=TraceOptions(batch_rays=2000), **kw).to_json_dict()


def test_execution_object_runs_as_the_keywords():
    here = _run()
    assert _run(execution=Execution(threads=2)) == here == _run(threads=2)
    assert _run(execution=Execution(threads=2), threads=2) == here  # the same value both ways is fine


def test_conflicts_and_bad_fields_are_refused():
    with pytest.raises(TraceError, match="threads given twice"):
        _run(execution=Execution(threads=2), threads=3)
    with pytest.raises(TraceError, match="workers must be a positive integer"):
        Execution(workers=0)
    with pytest.raises(TraceError, match="not both"):
        Execution(client=object(), scheduler="tcp://127.0.0.1:8786")
    assert Execution.merged(None, workers=2, progress=False) == Execution(workers=2)


def test_pst_sweep_takes_an_execution():
    """The same sweep with ``execution=Execution()`` (in process, no progress bar) as with the keywords."""
    from materials import Lambertian
    from straylight.analyses.builtin import tube_setup
    from straylight.analyses.pst import pst_sweep

    setup = tube_setup(material=Lambertian(rd=0.5), tolerance_mm=1.0)
    a = pst_sweep(setup, [0.3], n_rays=3000, seed=2, progress=False)
    b = pst_sweep(setup, [0.3], n_rays=3000, seed=2, execution=Execution())
    assert a.pst.tolist() == b.pst.tolist()
    with pytest.raises(TraceError, match="workers given twice"):
        pst_sweep(setup, [0.3], n_rays=3000, seed=2, workers=2, execution=Execution(workers=3))
