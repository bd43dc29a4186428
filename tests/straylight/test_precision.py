"""Ask for precision, not rays: rounds continue the chunk streams, merge exactly, and stop on a
reliable error estimate (straylight.analyses.precision)."""
import json
import math

import numpy as np
import pytest

from straylight.analyses.precision import Precision, merge_results, reliability, trace_to_precision
from straylight.cli.main import main
from straylight.rng import CHUNK_RAYS


@pytest.fixture(scope="module")
def tube():
    from straylight.analyses.builtin import tube_setup

    return tube_setup()


def _trace(tube, n, first_chunk=0, angle_deg=20.0, seed=3):
    from straylight.execution import Execution
    from straylight.trace import EstimatorOptions, TraceOptions, trace

    return trace(tube.scene, [tube.beam.source(math.radians(angle_deg))], n, seed, materials=tube.materials,
                 options=TraceOptions(estimator=EstimatorOptions(first_vertex_sampling=True)),
                 execution=Execution(first_chunk=first_chunk))


def test_rounds_continue_the_streams_and_merge_to_one_trace(tube):
    """trace(5000) == merge(trace(2000), trace(3000, Execution(first_chunk=2))): the same rays, pooled sums."""
    whole = _trace(tube, 5 * CHUNK_RAYS)
    merged = merge_results([_trace(tube, 2 * CHUNK_RAYS), _trace(tube, 3 * CHUNK_RAYS, first_chunk=2)])
    assert merged.n_rays == whole.n_rays
    for get in (lambda r: r.detectors["detector"], lambda r: r.absorbed["wall"], lambda r: r.escaped,
                lambda r: r.first_hit["vane_7"]):
        assert get(merged).power_w == pytest.approx(get(whole).power_w, rel=1e-12)
        assert get(merged).stderr_w == pytest.approx(get(whole).stderr_w, rel=1e-9)
    assert abs(merged.ledger["balance_residual_w"]) < 1e-9
    for k in (0, 1):
        np.testing.assert_allclose(merged.detector_chunks["detector"][k], whole.detector_chunks["detector"][k],
                                   rtol=1e-12, atol=0)
    # a different first chunk is a different stream: not the same numbers
    assert _trace(tube, 2 * CHUNK_RAYS, first_chunk=3).detectors["detector"].power_w != \
        _trace(tube, 2 * CHUNK_RAYS).detectors["detector"].power_w


def test_reliability_matches_the_exponential_kurtosis():
    """Per-ray x ~ Exp(1): relative error = std / (mean sqrt N) and VOV = (mu4 / sigma^4 - 1) / N = 8 / N
    (the exponential's kurtosis is 9; MCNP's VOV definition). The chunk estimate must find both."""
    rng = np.random.default_rng(7)
    n = 2_000_000
    x = rng.exponential(1.0, n)
    s1 = x.reshape(-1, CHUNK_RAYS).sum(axis=1)
    s2 = (x * x).reshape(-1, CHUNK_RAYS).sum(axis=1)
    rel = reliability(s1, s2, n)
    assert rel.rel_error == pytest.approx(np.std(x, ddof=1) * math.sqrt(n) / x.sum(), rel=1e-9)
    assert rel.vov == pytest.approx(8.0 / n, rel=0.15)
    assert rel.max_chunk_share < 0.01
    # one heavy ray carrying as much as all the others: the VOV and the chunk share show it
    x[12345] = x.sum()
    s1 = x.reshape(-1, CHUNK_RAYS).sum(axis=1)
    s2 = (x * x).reshape(-1, CHUNK_RAYS).sum(axis=1)
    heavy = reliability(s1, s2, n)
    assert heavy.vov > 0.5 and heavy.max_chunk_share > 0.99


def test_trace_to_precision_stops_on_target_and_is_reproducible(tube):
    src = [tube.beam.source(0.0)]
    from straylight.trace import EstimatorOptions, TraceOptions

    opts = TraceOptions(estimator=EstimatorOptions(first_vertex_sampling=True))
    target = Precision(0.002, first_rays=2000)
    runs = [trace_to_precision(tube.scene, src, 5, target, materials=tube.materials, options=opts,
                               detectors=["detector"]) for _ in range(2)]
    a, b = runs
    assert a.stop_reason == "target" and len(a.rounds) >= 2  # 2000 rays give ~0.6 %: it had to grow
    assert a.reliability["detector"].rel_error <= 0.002 and a.reliability["detector"].vov <= 0.1
    assert a.result.n_rays == b.result.n_rays and a.result.n_rays % CHUNK_RAYS == 0
    assert a.result.detectors["detector"].power_w == b.result.detectors["detector"].power_w
    # the merged rounds are the first N rays of one run of the same seed
    one = _trace(tube, a.result.n_rays, angle_deg=0.0, seed=5)
    assert a.result.detectors["detector"].power_w == pytest.approx(one.detectors["detector"].power_w, rel=1e-12)


def test_caps_say_what_stopped_the_run(tube):
    from straylight.trace import EstimatorOptions, TraceOptions

    run = trace_to_precision(tube.scene, [tube.beam.source(math.radians(20))], 1,
                             Precision(0.001, max_rays=3000, first_rays=2000), materials=tube.materials,
                             options=TraceOptions(estimator=EstimatorOptions(first_vertex_sampling=True)), detectors=["detector"])
    assert run.stop_reason == "max_rays" and run.result.n_rays == 3000


def test_pst_and_trace_cli_with_target(tmp_path, tube):
    from straylight.analyses.scene_setup import write_setup_scene

    out = tmp_path / "pst"
    assert main(["pst", "--builtin", "tube", "--angles-deg", "0", "20", "--target-rel-error", "0.03",
                 "--max-rays", "70000", "--seed", "2", "--out", str(out)]) == 0
    doc = json.loads((out / "pst.json").read_text())
    p0, p20 = doc["points"]
    assert doc["precision"]["target_rel_error"] == 0.03
    # the target stops a point only after the minimum sample (40 chunks) and a confirming look
    assert p0["stop_reason"] == "target" and p0["pst_stderr"] / p0["pst"] <= 0.03 and p0["rays"] >= 40_000
    assert p20["stop_reason"] in ("target", "max_rays") and 40_000 <= p20["rays"] <= 70000
    assert "vov" in p20 and "stop_reason" in (out / "pst.csv").read_text()
    scene = write_setup_scene(tube, tmp_path / "scene")
    assert main(["trace", str(scene), "--target-rel-error", "0.05", "--max-rays", "6000", "--seed", "1",
                 "--json", str(tmp_path / "t.json")]) == 0
    t = json.loads((tmp_path / "t.json").read_text())
    # 6000 rays are below the minimum sample (40 chunks of 1000): the cap stops it, whatever the error
    assert t["precision"]["stop_reason"] == "max_rays" and t["rays"] == t["precision"]["rays"] == 6000


@pytest.mark.parametrize("argv, message", [
    (["pst", "--builtin", "tube", "--rays", "100", "--target-rel-error", "0.1", "--out", "x"], "not allowed with"),
    (["pst", "--builtin", "tube", "--max-rays", "1e5", "--out", "x"], "--max-rays need --target-rel-error"),
    (["pst", "--builtin", "tube", "--target-rel-error", "2", "--out", "x"], "--target-rel-error must be in (0, 1)"),
])
def test_bad_precision_args(argv, message, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) if "not allowed" in message else _nothing():
        rc = main(argv)
        assert rc == 2
    assert message in capsys.readouterr().err


class _nothing:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def test_study_report_shows_the_precision_stop(tmp_path):
    out = tmp_path / "study"
    assert main(["study", "--target-rel-error", "0.01", "--max-rays", "70000", "--angles-deg", "0", "20",
                 "--rays", "1000", "--no-sweep", "--seed", "2", "--out", str(out)]) == 0
    doc = json.loads((out / "results.json").read_text())
    assert doc["pst"]["precision"]["target_rel_error"] == 0.01
    stops = [p["stop_reason"] for p in doc["pst"]["points"]]
    assert stops[0] == "target" and stops[1] == "max_rays"
    page = (out / "index.html").read_text()
    assert "stopped by" in page and "max_rays" in page and "VOV" in page


def test_loose_execution_keywords_of_trace_still_work_with_a_warning(tube):
    """``trace(..., first_chunk=K, intersector=I)`` (the old spelling, one release): the numbers of
    ``execution=Execution(first_chunk=K, intersector=I)`` and a DeprecationWarning naming the new one."""
    from straylight.execution import Execution
    from straylight.intersect import EmbreeIntersector
    from straylight.trace import EstimatorOptions, TraceError, TraceOptions, trace

    args = (tube.scene, [tube.beam.source(math.radians(20.0))], CHUNK_RAYS, 3)
    kw = {"materials": tube.materials, "options": TraceOptions(estimator=EstimatorOptions(first_vertex_sampling=True))}
    new = trace(*args, **kw, execution=Execution(first_chunk=2))
    with pytest.warns(DeprecationWarning, match=r"trace\(first_chunk=\.\.\.\) is deprecated.*Execution\(first_chunk"):
        old = trace(*args, **kw, first_chunk=2)
    assert old.to_json_dict() == new.to_json_dict()
    isect = EmbreeIntersector(tube.scene.triangles_mm)
    with pytest.warns(DeprecationWarning, match=r"trace\(intersector=\.\.\.\)"):
        trace(*args, **kw, intersector=isect)
    with pytest.raises(TraceError, match="first_chunk must be a non-negative integer"):
        trace(*args, **kw, execution=Execution(first_chunk=-1))
    with pytest.raises(TypeError, match="unexpected keyword argument 'chunk'"):
        trace(*args, **kw, chunk=2)


def test_looking_ahead_keeps_the_looks_and_the_stop(tube):
    """Tracing on to the earliest look that can stop (fewer walk calls) gives the same looks, the same stop
    and the same rays as one call per look: here the first calls end inside looks that do not meet the
    target (a small first round, a target the minimum sample does not meet), so several looks are read
    from the first rays of a longer call."""
    from straylight.analyses.precision import traced_before_look
    from straylight.trace import EstimatorOptions, TraceOptions

    opts = TraceOptions(estimator=EstimatorOptions(first_vertex_sampling=True))
    target = Precision(0.012, first_rays=3000, min_chunks=8)
    src = [tube.beam.source(math.radians(10))]
    ahead, plain = (trace_to_precision(tube.scene, src, 3, target, materials=tube.materials, options=opts,
                                       detectors=["detector"], look_ahead=flag) for flag in (True, False))
    assert plain.stop_reason == ahead.stop_reason == "target" and len(plain.rounds) >= 4
    assert [n for n, _, _ in ahead.rounds] == [n for n, _, _ in plain.rounds]
    for (_, e1, v1), (_, e2, v2) in zip(ahead.rounds, plain.rounds):
        assert e1 == pytest.approx(e2, rel=1e-9) and v1 == pytest.approx(v2, rel=1e-9, abs=1e-15)
    a, b = ahead.result.detectors["detector"], plain.result.detectors["detector"]
    assert ahead.result.n_rays == plain.result.n_rays
    assert a.power_w == pytest.approx(b.power_w, rel=1e-12) and a.stderr_w == pytest.approx(b.stderr_w, rel=1e-9)
    # where it traces to: a look that can stop is traced to itself, any other to the confirming look of
    # the earliest look that can meet the target (the minimum sample at least), within the ray cap
    rule = Precision(0.02)
    assert traced_before_look([], 20_000, rule) == 60_000
    assert traced_before_look([], 50_000, rule) == 75_000
    assert traced_before_look([], 20_000, Precision(0.02, max_rays=30_000)) == 30_000
    from straylight.stop_rule import Look

    met = Look(40_000, 1.0, 0.01, 0.0, 0.01, 40)
    assert traced_before_look([met], 60_000, rule) == 60_000
    # under a time cap: the first call looks ahead only under a long cap; later ones as far as time allows
    from straylight.analyses.precision import _traced_ahead

    assert _traced_ahead([], 20_000, Precision(0.02, max_seconds=5.0), 0, 0.0) == 20_000
    assert _traced_ahead([], 20_000, Precision(0.02, max_seconds=60.0), 0, 0.0) == 60_000
    assert _traced_ahead([], 40_000, Precision(0.02, max_seconds=60.0), 20_000, 10.0) == 60_000
    assert _traced_ahead([], 40_000, Precision(0.02, max_seconds=60.0), 20_000, 45.0) == 40_000
    assert _traced_ahead([], 40_000, Precision(0.02, max_seconds=60.0), 20_000, 25.0) == 48_000  # 35 s at 800 rays/s
