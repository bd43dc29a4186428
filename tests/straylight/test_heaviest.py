"""A point whose error bar is flagged names the ray and path family that hold its variance
(straylight.analyses.heaviest): the retraced chunk must reproduce the run's, and the ray it names must
be the one a whole trace with path records finds."""
import json
import math
from dataclasses import replace

import numpy as np
import pytest

from straylight.analyses.grid import TraceJob
from straylight.analyses.heaviest import LENS_HINT, chunk_spread, heaviest_path, untrusted
from straylight.trace import EstimatorOptions, OutputOptions, TraceOptions, trace
from test_lens_vertex import _lens_scene

N_RAYS = 6000
SEED = 5


@pytest.fixture(scope="module")
def lens():
    sc, src, mats = _lens_scene()
    return TraceJob(sc, src, mats, TraceOptions(estimator=EstimatorOptions(delta_chain=4)), "det")


def _per_ray(job, n, seed):
    """Each ray's detector contribution from a whole trace with path records (independent of the chunk retrace)."""
    opts = replace(job.options, output=OutputOptions(record_paths=True, path_depth=16))
    res = trace(job.scene, job.sources, n, seed, materials=job.materials, options=opts)
    p = res.paths
    sel = np.flatnonzero(np.asarray(p.detector) == list(p.part_names).index(job.detector))
    x = np.bincount(np.asarray(p.ray)[sel], weights=np.asarray(p.power_w)[sel], minlength=n)
    return res, x, p, sel


def test_names_the_ray_a_whole_recorded_trace_finds(lens):
    res = trace(lens.scene, lens.sources, N_RAYS, SEED, materials=lens.materials, options=lens.options)
    got = heaviest_path(lens, SEED, res)
    whole, x, p, sel = _per_ray(lens, N_RAYS, SEED)
    assert whole.detectors["det"].power_w == pytest.approx(res.detectors["det"].power_w, rel=1e-12)
    assert x.sum() == pytest.approx(res.detectors["det"].power_w, rel=1e-9)  # the records are the whole tally
    mean = x.mean()
    d2 = (x - mean) ** 2
    c = int(np.argmax(d2.reshape(-1, 1000).sum(axis=1)))  # the chunk that holds most of the variance
    top = 1000 * c + int(np.argmax(d2[1000 * c:1000 * (c + 1)]))  # its heaviest ray
    assert got is not None
    assert got["ray"] == top
    assert got["contribution_w"] == pytest.approx(x[top], rel=1e-9)
    assert got["variance_share"] == pytest.approx(d2[top] / d2.sum(), rel=1e-6)
    # its family: the label `paths --group-by family` gives its largest record
    rows = sel[np.asarray(p.ray)[sel] == top]
    biggest = rows[np.argmax(np.abs(np.asarray(p.power_w)[rows]))]
    kinds = [kind for _, kind in p.describe(int(biggest))]
    assert got["family"].startswith("source -> ") and got["family"].endswith(" -> det")
    assert got["family"].count("(specular)") == kinds.count("specular")
    # the lens set is named when the first scatter point was reached through the glass alone (here the beam's
    # edge passes beside the singlet and lights the plate straight too)
    events = p.describe(int(biggest))
    first = [kind for _, kind in events].index("scatter")
    through = first > 0 and all(part.startswith("lens_") for part, _ in events[:first])
    assert got["hint"] == (LENS_HINT if through else None)


def test_lit_through_the_lens_alone_names_the_lens_set():
    sc, src, mats = _lens_scene(tilt_deg=0.0)  # the whole beam enters the singlet: the plate is lit through it
    job = TraceJob(sc, src, mats, TraceOptions(estimator=EstimatorOptions(delta_chain=4)), "det")
    res = trace(sc, src, 3000, SEED, materials=mats, options=job.options)
    got = heaviest_path(job, SEED, res)
    assert got["family"].startswith("source -> lens_front (specular) -> lens_back (specular) -> plate")
    assert got["hint"] == LENS_HINT


def test_no_hint_with_the_lens_set_on_or_when_lit_straight(lens):
    on = replace(lens, options=replace(lens.options, estimator=replace(lens.options.estimator, lens_vertex=True)))
    res = trace(on.scene, on.sources, 3000, SEED, materials=on.materials, options=on.options)
    assert heaviest_path(on, SEED, res)["hint"] is None
    from straylight.analyses.builtin import tube_setup

    tube = tube_setup()
    job = TraceJob(tube.scene, [tube.beam.source(math.radians(20.0))], tube.materials, TraceOptions(), "detector")
    res = trace(job.scene, job.sources, 3000, 2, materials=job.materials, options=job.options)
    got = heaviest_path(job, 2, res)
    assert got is not None and got["hint"] is None and "(specular)" not in got["family"]


def test_a_chunk_that_does_not_reproduce_names_nothing(lens):
    """Another seed's chunks are other rays: the retrace's sum differs, so no ray is named."""
    res = trace(lens.scene, lens.sources, 3000, SEED, materials=lens.materials, options=lens.options)
    assert heaviest_path(lens, SEED + 1, res) is None


def test_chunk_spread_is_the_reliability_rule():
    rng = np.random.default_rng(3)
    x = rng.exponential(1.0, 2500)
    s1 = np.add.reduceat(x, [0, 1000, 2000])
    s2 = np.add.reduceat(x * x, [0, 1000, 2000])
    c = chunk_spread(s1, s2, len(x))
    m = x.mean()
    expect = [np.sum((x[a:b] - m) ** 2) for a, b in ((0, 1000), (1000, 2000), (2000, 2500))]
    np.testing.assert_allclose(c, expect, rtol=1e-9)


def test_untrusted_follows_the_flags():
    assert untrusted({"vov": 0.3}, 0.05)
    assert untrusted({"vov": 0.01, "stop_reason": "max_seconds"}, 0.05)
    assert not untrusted({"vov": 0.01, "stop_reason": "target"}, 0.01)
    assert not untrusted({"vov": 0.5}, 1e-7)  # an error bar under 1e-5 of the point is not flagged
    assert not untrusted({"vov": float("nan")}, 0.05)


def test_a_capped_pst_point_carries_it_into_pst_json(tmp_path, capsys):
    from straylight.cli.main import main

    code = main(["pst", "--builtin", "tube", "--angles-deg", "20", "--target-rel-error", "1e-4", "--max-rays", "3000",
                 "--seed", "1", "--out", str(tmp_path)])
    assert code == 0
    point = json.loads((tmp_path / "pst.json").read_text())["points"][0]
    assert point["stop_reason"] == "max_rays"
    heavy = point["heaviest_path"]
    assert heavy["family"].startswith("source -> ") and 0 < heavy["variance_share"] <= 1
    assert 0 <= heavy["ray"] < point["rays"]
    assert f"of its variance: {heavy['family']}" in capsys.readouterr().out


def test_the_study_warning_renders_every_code_span():
    from straylight.analyses.report import _html_warning

    out = _html_warning("**Warning: x** (`a`). At 15 deg one ray: b (`--estimators lens` c).")
    assert out.count("<code>") == 2 and "`" not in out and out.count("<strong>") == 1


def test_the_study_warning_names_the_heaviest_path_per_flagged_angle():
    from straylight.analyses.report import _pst_reliability_note

    class _Pst:
        def flagged_rows(self):
            heavy = {"family": "source -> lens_front (specular) -> lens_cell -> det", "variance_share": 0.97,
                     "ray": 12, "contribution_w": 1e-8, "hint": LENS_HINT}
            return [{"off_axis_deg": 15.0, "flags": "unreliable_error", "vov": 0.9, "heaviest_path": heavy},
                    {"off_axis_deg": 20.0, "flags": "", "vov": 0.01}]

    note = _pst_reliability_note(_Pst())
    assert "at 15 deg" in note.split("**")[1] and "20" not in note.split("**")[1]
    assert "At 15 deg one ray holds 97% of the variance: source -> lens_front (specular) -> lens_cell -> det" in note
    assert "`--estimators lens`" in note


def test_a_lit_point_seen_through_a_ghost_names_the_ghosts_set():
    """The heaviest path "P (lit straight) -> lens_front -> lens_back -> lens_front -> lens_back" (a singlet's
    two-reflection ghost) names ``--estimators ghosts``; a path through the glass in another order, a path whose P is
    lit through the lens, or a set with the ghosts on does not."""
    from straylight.analyses.heaviest import GHOST_HINT, _seen_through_a_ghost

    sc, src, mats = _lens_scene()
    job = TraceJob(sc, src, mats, TraceOptions(estimator=EstimatorOptions(delta_chain=4)), "det")
    ghost = [("plate", "scatter"), ("lens_front", "specular"), ("lens_back", "specular"), ("lens_front", "specular"),
             ("lens_back", "specular")]
    assert _seen_through_a_ghost(job, ghost)
    assert not _seen_through_a_ghost(job, ghost[:3])  # two refractions
    assert not _seen_through_a_ghost(job, [ghost[0], ghost[1], ghost[2], ghost[2], ghost[1]])
    assert not _seen_through_a_ghost(job, [("lens_front", "specular")] + ghost[1:])
    assert "--estimators ghosts" in GHOST_HINT.replace("`", "").replace("\n", " ")
