"""The entrance table's lens component (straylight.engine.strategies.entrance, LENS_COMPONENT): a share of the
entrance points drawn where the beam lights, through a lens, the scatter points a detector sees
(straylight.engine.lens_vertex.glint_entrances on lens_vertex's table).

Scene: test_lens_vertex.py's singlet over a glossy plate, seen straight by a small detector; its checks: the
entrance points the component holds do light the plate through the lens (traced forward), the mixture is the
table's and the component's at their shares, and a trace with entrance sampling (the component in its table)
agrees with the analog walk.
"""
import math

import numpy as np
import pytest

from engine_helpers import assert_agrees_with_analog
from straylight.engine import entrance_sampling, lens_vertex
from straylight.engine.strategies import entrance
from straylight.sources import orthonormal_basis
from straylight.trace import EstimatorOptions, TraceOptions, make_spec, trace
from test_lens_vertex import _lens_scene


def test_the_glint_entrances_light_the_table_points_through_the_lens():
    sc, src, mats = _lens_scene(plate_material="glossy")
    spec = make_spec(sc, src, 1000, 1, mats, TraceOptions(estimator=EstimatorOptions(lens_vertex=True)))
    from straylight.engine.runtime import runtime

    comp = runtime().scene(spec, None)
    table = lens_vertex.build_table(spec, comp)
    assert not table.empty
    u = lens_vertex.glint_entrances(spec, table, 2000, (1, 2))
    assert len(u) > 1000  # (a table triangle may be lit in part: points outside the beam have no entrance point)
    assert np.all((u >= 0.0) & (u < 1.0))
    # forward: the disk point of each, refracted through the singlet, lands on the plate (z = -20, x -10..30)
    t, b = orthonormal_basis(src.normal)  # the basis CollimatedDisk.emit draws its points in
    r = src.radius_mm * np.sqrt(u[:, 0])
    phi = 2 * np.pi * u[:, 1]
    points = src.center_mm + (r * np.cos(phi))[:, None] * t + (r * np.sin(phi))[:, None] * b
    ab, _ = lens_vertex._to_disk(src, points)
    crossings, d, ok = lens_vertex.trace_run(spec, table.runs[0], ab)
    assert ok.all()
    X = crossings[-1]
    hit = X + ((-20.0 - X[:, 2]) / d[:, 2])[:, None] * d
    assert np.all((hit[:, 0] > -10.5) & (hit[:, 0] < 30.5) & (np.abs(hit[:, 1]) < 20.5)), hit[:5]


def test_the_mixture_keeps_the_table_and_adds_the_component_at_its_share():
    g = 8
    prob = np.full(g * g, 1.0 / (g * g))
    table = entrance_sampling.EntranceTable(grid=g, prob=prob, cdf=np.cumsum(prob), pilot_rays=10, pilot_hits=1)
    u = np.array([[0.01, 0.01], [0.01, 0.02], [0.99, 0.5]])  # two in cell 0, one in cell (7, 4)
    mixed = entrance_sampling.with_component(table, u, 0.1)
    expected = 0.9 * prob
    expected[0] += 0.1 * 2 / 3
    expected[7 * g + 4] += 0.1 / 3
    np.testing.assert_allclose(mixed.prob, expected, rtol=1e-12)
    assert mixed.cdf[-1] == 1.0
    assert entrance_sampling.with_component(table, np.zeros((0, 2)), 0.1) is table


@pytest.fixture(scope="module")
def glossy_lens():
    return _lens_scene(plate_material="glossy")


def test_a_trace_with_the_component_agrees_with_the_analog_walk(glossy_lens, monkeypatch):
    sc, src, mats = glossy_lens
    made = []
    original = entrance_sampling.with_component

    def recording(table, u, share):
        made.append((table, len(u), share))
        return original(table, u, share)

    monkeypatch.setattr(entrance_sampling, "with_component", recording)
    est = EstimatorOptions(delta_chain=4, entrance_sampling=True)
    res = trace(sc, src, 20_000, seed=3, materials=mats, options=TraceOptions(estimator=est))
    assert made and made[0][1] > 0 and made[0][2] == entrance.LENS_COMPONENT  # the component went in
    analog = trace(sc, src, 300_000, seed=4, materials=mats, options=TraceOptions(estimator=EstimatorOptions(nee=False)))
    assert_agrees_with_analog(res, analog)
    assert math.isfinite(res.detectors["det"].stderr_w)
