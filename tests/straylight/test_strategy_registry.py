"""The strategies' registry (straylight.engine.strategies): the estimator table is derived from it, the
engine's modules reach the strategies only through it and their hooks, and a strategy added to it runs
its hooks in the walk without any other file changing (the recipe of docs/engine.md, "Strategies")."""
from __future__ import annotations

import ast
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from straylight.engine.capabilities import Capability
from straylight.engine.estimators import ESTIMATORS
from straylight.engine.strategies import registry
from straylight.engine.strategies.base import ANALOG, Estimator, Strategy
from straylight.trace import OutputOptions, TraceOptions, trace

from tests.straylight.test_engine_contract import CONTRACT_SCENES, _source

ENGINE = Path(__file__).resolve().parents[2] / "straylight" / "engine"


def test_the_estimator_table_is_the_registry():
    assert ESTIMATORS == tuple(s.estimator for s in registry.STRATEGIES)
    assert len(registry.BY_NAME) == len(registry.STRATEGIES)  # one name each
    assert sum(s.shapes_emission for s in registry.STRATEGIES) <= 1


def _engine_imports(path: Path) -> set[str]:
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            out.add(node.module)
            out.update(f"{node.module}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
    return out


def test_nee_and_the_chains_reach_other_strategies_only_through_the_walk():
    """NEE imports none of the strategies it works with (the walk hands it their hooks), and delta_chain
    none of optical_surface's internals (they share straylight.engine.surface_geometry)."""
    nee = _engine_imports(ENGINE / "nee.py")
    for other in ("second_vertex", "diffraction", "targets", "first_vertex", "strategies"):
        assert f"straylight.engine.{other}" not in nee, other
    chains = _engine_imports(ENGINE / "delta_chain.py")
    assert not any(m.startswith("straylight.engine.interactions") for m in chains), chains
    # no engine module outside the registry compares a strategy's name
    for path in (ENGINE / "plan.py", ENGINE / "walk.py"):
        assert ".name ==" not in path.read_text() and "name.startswith" not in path.read_text(), path


class _Probe(Strategy):
    """A strategy that only watches: it asks for per-event uniforms when ``columns`` > 0."""

    estimator = Estimator("probe", replace(ANALOG, nee=True), Capability.NONE, diffraction=True)
    state_key = "probe"
    columns = 0

    def uniform_columns(self, spec) -> int:
        return self.columns

    def batch_state(self, ctx):
        return {"events": 0, "hits": 0, "interfaces": 0, "nee": 0, "u": [], "batches": 1}

    def share_walk_hits(self, state, event, rec, rec_w):
        state["hits"] += len(rec)
        return rec, rec_w

    def after_hits(self, state, event, continuing) -> None:
        state["events"] += 1
        assert event.states["probe"] is state
        if self.columns:
            c = event.columns.of("probe")
            state["u"].append(event.uniforms[:, c:c + self.columns].copy())

    def nee_weights(self, state, event, verts, w_vertex):
        state["nee"] += len(verts)
        return w_vertex

    def after_walk(self, state, ctx) -> int:
        _Probe.seen.append(state)
        return 0


@pytest.mark.parametrize("columns", [0, 2])
def test_a_strategy_added_to_the_registry_runs_its_hooks(monkeypatch, columns):
    case = CONTRACT_SCENES["surface_response (scatter)"]()
    probe = _Probe()
    probe.columns = columns
    _Probe.seen = []
    opts = TraceOptions(estimator=replace(ANALOG, nee=True), output=OutputOptions(record_paths=True))
    before = trace(case.scene, _source(), 3000, seed=3, materials=case.materials, options=opts)
    monkeypatch.setattr(registry, "STRATEGIES", (*registry.STRATEGIES, probe))
    after = trace(case.scene, _source(), 3000, seed=3, materials=case.materials, options=opts)
    assert "probe" in after.strategies.on
    assert len(_Probe.seen) >= 1
    seen = _Probe.seen[0]
    assert seen["events"] > 0 and seen["nee"] > 0 and seen["hits"] > 0
    if columns == 0:  # watching changes nothing, to the bit
        assert after.detectors["detector"].power_w == before.detectors["detector"].power_w
        assert np.array_equal(after.paths.power_w, before.paths.power_w)
    else:  # its columns come after the others': uniforms of its own
        u = np.concatenate(seen["u"])
        assert u.shape[1] == columns and len(u) > 0 and (u >= 0).all() and (u < 1).all()
        assert 0.4 < u.mean() < 0.6
