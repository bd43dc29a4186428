"""``Execution``: where a trace runs, in one object; the numbers never depend on it, and
``trace`` and every analysis take it instead of execution keywords."""
from __future__ import annotations

import importlib
import inspect
import pkgutil

import pytest

import straylight.analyses
import straylight.design
from straylight.execution import FIELDS, Execution
from straylight.trace import TraceError, TraceOptions, trace
from test_engine_contract import CONTRACT_SCENES, _source


def _run(**kw):
    case = CONTRACT_SCENES["surface_response (scatter)"]()
    return trace(case.scene, _source(), 6000, seed=3, materials=case.materials,
                 options=TraceOptions(batch_rays=2000), **kw).to_json_dict()


def test_execution_on_threads_gives_the_numbers_of_this_process():
    here = _run()
    assert here["detectors"]["detector"]["power_w"] > 0  # the scene couples: the comparison is not 0 == 0
    assert _run(execution=Execution(threads=2)) == here


def test_bad_fields_are_refused():
    with pytest.raises(TraceError, match="workers must be a positive integer"):
        Execution(workers=0)
    with pytest.raises(TraceError, match="threads must be a positive integer"):
        Execution(threads=True)
    with pytest.raises(TraceError, match="not both"):
        Execution(client=object(), scheduler="tcp://127.0.0.1:8786")
    with pytest.raises(TraceError, match="execution must be a straylight.execution.Execution"):
        _run(execution={"threads": 2})


# the public entry points that trace: each takes ``execution``
ENTRY_POINTS = {
    "straylight.trace": ["trace"],
    "straylight.analyses.precision": ["trace_to_precision"],
    "straylight.analyses.grid": ["run_grid"],
    "straylight.analyses.pst": ["pst_sweep"],
    "straylight.analyses.sweep": ["design_sweep"],
    "straylight.analyses.model": ["model_sweep"],
    "straylight.analyses.report": ["run_study"],
    "straylight.analyses.telescope": ["run_telescope_study"],
    "straylight.analyses.paths_report": ["paths_analysis"],
    "straylight.analyses.critical": ["critical_objects"],
    "straylight.design.vanes": ["design_vanes"],
    "straylight.design.refine": ["refine"],
    "straylight.design.evaluate": ["pst_points"],
    "straylight.api": ["Instrument.pst", "Instrument.paths", "Instrument.critical"],
}


def _modules():
    names = {"straylight.trace", "straylight.api"}
    for pkg in (straylight.analyses, straylight.design):
        names |= {f"{pkg.__name__}.{m.name}" for m in pkgutil.iter_modules(pkg.__path__)}
    return sorted(names)


def _callables(module):
    """Public functions of ``module`` defined there, and the public methods of its public classes."""
    for name, obj in vars(module).items():
        if name.startswith("_") or getattr(obj, "__module__", None) != module.__name__:
            continue
        if inspect.isfunction(obj):
            yield name, obj
        elif inspect.isclass(obj):
            for m, f in vars(obj).items():
                if inspect.isfunction(f) and not m.startswith("_"):
                    yield f"{name}.{m}", f


def test_every_analysis_entry_point_takes_an_execution_and_no_execution_keywords():
    """Introspected signatures: no public function of trace, the analyses, the design package or the
    notebook API has a parameter named like an Execution field (workers, client, scheduler, threads,
    security, progress); the entry points that trace take ``execution``."""
    offenders = []
    for name in _modules():
        module = importlib.import_module(name)
        for qual, fn in _callables(module):
            bad = sorted(set(inspect.signature(fn).parameters) & set(FIELDS))
            if bad:
                offenders.append(f"{name}.{qual}({', '.join(bad)})")
    assert offenders == [], "execution keywords left: " + "; ".join(offenders)
    for name, quals in ENTRY_POINTS.items():
        module = importlib.import_module(name)
        for qual in quals:
            obj = module
            for part in qual.split("."):
                obj = getattr(obj, part)
            assert "execution" in inspect.signature(obj).parameters, f"{name}.{qual} takes no execution"


def test_the_command_line_builds_its_execution_in_one_place():
    """Only straylight/cli/cluster_args.py turns flags into an Execution or a dask client; every
    command that traces goes through its ``execution(args)``."""
    from pathlib import Path

    cli = Path(straylight.analyses.__file__).resolve().parents[1] / "cli"
    elsewhere = [f"{p.name}: {word}" for p in sorted(cli.glob("*.py")) if p.name != "cluster_args.py"
                 for word in ("Execution(", "dask_client(", "cluster_client(") if word in p.read_text()]
    assert elsewhere == []
    users = sorted(p.name for p in cli.glob("*.py") if "cluster_args import execution" in p.read_text())
    assert {"trace.py", "pst.py", "study.py", "paths.py", "critical.py", "design.py"} <= set(users)
