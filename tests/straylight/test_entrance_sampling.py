"""Entrance sampling (EstimatorOptions.entrance_sampling, straylight.engine.entrance_sampling): the
source's entrance points drawn from a pilot-learnt density, each ray weighted by 1 / density.

Scene: the glass slab of test_delta_chain.py (10 mm, n = 1.5, at 45 deg) under a wide collimated
beam (radius 15 mm) with a 4 mm detector below: only the entrance points over small parts of the
beam (the detector's footprint shifted back along the transmitted beam's path and along the
two-reflection ghost's) reach it, as behind a refractor's lens."""
import math

import numpy as np
import pytest

from engine_helpers import disk_part
from geometry.mesh import Part, Scene
from materials import load_material
from straylight.engine import entrance_sampling
from straylight.engine.entrance_sampling import table_from_contributions, warp
from straylight.sources import CollimatedDisk
from straylight.trace import EstimatorOptions, TraceOptions, trace

N = 1.5
THICK_MM = 10.0
ANALOG = TraceOptions(estimator=EstimatorOptions(nee=False))
ENTRANCE = TraceOptions(estimator=EstimatorOptions(nee=False, entrance_sampling=True))


@pytest.fixture(scope="module")
def wide_slab():
    v_top = np.array([[-100.0, -100.0, 0.0], [100.0, -100.0, 0.0], [100.0, 100.0, 0.0], [-100.0, 100.0, 0.0]])
    top = Part("top", v_top, np.array([[0, 1, 2], [0, 2, 3]]), material="glass", role="surface")
    bottom = Part("bottom", v_top - [0.0, 0.0, THICK_MM], np.array([[0, 2, 1], [0, 3, 2]]), material="glass",
                  role="surface")
    shift = THICK_MM * math.tan(math.asin(math.sin(math.radians(45.0)) / N))
    det = disk_part("det", -20.0, 4.0, 64, role="detector")
    det = Part("det", det.vertices_mm + np.array([3 * shift + 10.0, 0.0, 0.0]), det.faces, role="detector")
    d = np.array([math.sqrt(0.5), 0.0, -math.sqrt(0.5)])
    src = CollimatedDisk(center_mm=[-20.0, 0.0, 20.0], normal=d, direction=d, radius_mm=15.0)
    mats = {"glass": load_material({"components": [{"type": "dielectric", "n": N}]}, "glass")}
    return Scene((top, bottom, det)), src, mats


@pytest.mark.parametrize("guide_hits", [None, 100])
def test_agrees_with_the_analog_walk_at_a_smaller_error(wide_slab, guide_hits, monkeypatch):
    """Also with the pilot's second stage drawn from its first stage's table (its first stage has ~470
    lit rays: 100 lets them guide)."""
    sc, src, mats = wide_slab
    if guide_hits is not None:
        monkeypatch.setattr(entrance_sampling, "PILOT_GUIDE_HITS", guide_hits)
    analog = trace(sc, src, 200_000, seed=11, materials=mats, options=ANALOG)
    on = trace(sc, src, 40_000, seed=12 if guide_hits is None else 13, materials=mats, options=ENTRANCE)
    a, b = analog.detectors["det"], on.detectors["det"]
    assert a.power_w > 0 and b.power_w > 0
    assert abs(a.power_w - b.power_w) <= 4 * math.hypot(a.stderr_w, b.stderr_w), (a, b)
    # at equal rays the analog walk's error would be sqrt(5) x its own: the entrance points cut it
    assert b.stderr_w / b.power_w < 0.5 * math.sqrt(5.0) * a.stderr_w / a.power_w
    # w0 - w of each ray is booked as escaped: the ledger still closes to round-off
    assert abs(on.ledger["balance_residual_w"]) < 1e-9 * on.emitted_w


def test_results_do_not_depend_on_the_batch_size(wide_slab):
    sc, src, mats = wide_slab
    runs = [trace(sc, src, 6_000, seed=3, materials=mats,
                  options=TraceOptions(estimator=ENTRANCE.estimator, batch_rays=b)) for b in (1_000, 6_000)]
    assert runs[0].detectors["det"].power_w == runs[1].detectors["det"].power_w


def test_the_warp_has_the_table_density_and_unit_mean_weight():
    """Rays land in cell c with probability P_c, uniformly inside it, and carry 1 / (G^2 P_c): the
    weighted mean of any g(u) is its integral over the unit square (here g = u1 + u2^2: 1/2 + 1/3)."""
    rng = np.random.default_rng(5)
    u0 = rng.random((20_000, 2))
    x = np.where((u0[:, 0] > 0.3) & (u0[:, 0] < 0.35) & (u0[:, 1] < 0.1), 1.0, 0.0)  # a small bright region
    table = table_from_contributions(u0, x)
    assert table is not None and table.prob.min() >= entrance_sampling.DEFENSIVE / table.grid ** 2 * 0.999
    u = rng.random((400_000, 2))
    w = warp(table, u)
    assert u.min() >= 0.0 and u.max() < 1.0
    g = table.grid
    cell = np.minimum((u[:, 0] * g).astype(int), g - 1) * g + np.minimum((u[:, 1] * g).astype(int), g - 1)
    np.testing.assert_allclose(w, 1.0 / (g * g * table.prob[cell]))
    counts = np.bincount(cell, minlength=g * g)
    big = table.prob > 10.0 / g ** 2
    assert big.any()
    expected = len(u) * table.prob[big]  # binomial counts: within 5 sigma in every bright cell
    assert np.all(np.abs(counts[big] - expected) < 5.0 * np.sqrt(expected) + 1.0)
    assert abs(counts[big].sum() - expected.sum()) < 4.0 * math.sqrt(expected.sum())
    est = w * (u[:, 0] + u[:, 1] ** 2)
    assert abs(est.mean() - 5.0 / 6.0) < 4 * est.std() / math.sqrt(len(u))
    assert abs(w.mean() - 1.0) < 4 * w.std() / math.sqrt(len(u))


def test_the_scales_mix_at_their_weights():
    """P_c = d / G^2 + (1 - d) sum_s a_s q_s(c) with the weights normalised: weight 0 drops a scale, equal weights
    average them, and the default set of scales takes SCALE_WEIGHTS (the coarse grids a small share)."""
    rng = np.random.default_rng(11)
    u = rng.random((20_000, 2))
    x = np.where((u[:, 0] > 0.3) & (u[:, 0] < 0.35) & (u[:, 1] < 0.1), 1.0, 0.0)
    d = entrance_sampling.DEFENSIVE

    def mixed(scales, weights=None):
        t = table_from_contributions(u, x, scales=scales, scale_weights=weights)
        return (t.prob - d / t.grid ** 2) / (1.0 - d)

    fine, coarse = mixed((256,)), mixed((4,))
    np.testing.assert_allclose(mixed((256, 4), (1.0, 0.0)), fine, atol=1e-15)
    np.testing.assert_allclose(mixed((256, 4)), 0.5 * fine + 0.5 * coarse, atol=1e-15)
    np.testing.assert_allclose(mixed((256, 4), (3.0, 1.0)), 0.75 * fine + 0.25 * coarse, atol=1e-15)
    a = np.asarray(entrance_sampling.SCALE_WEIGHTS) / sum(entrance_sampling.SCALE_WEIGHTS)
    parts = [mixed((s,)) for s in entrance_sampling.SCALES]
    np.testing.assert_allclose(mixed(entrance_sampling.SCALES), sum(w * q for w, q in zip(a, parts)), atol=1e-15)
    with pytest.raises(ValueError, match="scale_weights must be 2 non-negative numbers"):
        table_from_contributions(u, x, scales=(256, 4), scale_weights=(1.0,))
    with pytest.raises(ValueError, match="scale_weights"):
        table_from_contributions(u, x, scales=(256, 4), scale_weights=(0.0, 0.0))


def test_no_table_without_a_pilot_hit():
    assert table_from_contributions(np.random.default_rng(0).random((100, 2)), np.zeros(100)) is None


def test_the_analyses_turn_it_on_only_with_a_refracting_material(wide_slab):
    from materials import Lambertian
    from straylight.analyses.estimators import estimator_options

    _, _, mats = wide_slab
    assert estimator_options("default", materials=mats).estimator.entrance_sampling
    assert not estimator_options("default", materials={"black": Lambertian(0.05)}).estimator.entrance_sampling


def test_the_pilot_runs_without_the_reverse_chains(wide_slab):
    """The pilot learns which entrance points matter; the reverse chains' source connections do not
    depend on the entrance point (each ray's eye chains are drawn on their own), so the pilot runs
    without them, with at most PILOT_NEE_SPLIT NEE samples at a glint (docs/engine.md, "The pilot's
    cost"), and with every other estimator of the trace."""
    from straylight.trace import make_spec

    sc, src, mats = wide_slab
    opts = TraceOptions(estimator=EstimatorOptions(entrance_sampling=True, reverse_chain=4, delta_chain=4,
                                                   nee_split=64, tree_split=4, specular_nee=1))
    spec = make_spec(sc, src, 1_000, 5, mats, opts)
    seen = []

    def run_batch(pilot, first, stop, intersector):
        seen.append(pilot.options.estimator)
        return {}

    entrance_sampling.build_table(spec, run_batch, n_rays=2_000)
    (est,) = seen
    assert est.reverse_chain == 0 and not est.entrance_sampling and est.nee_split == entrance_sampling.PILOT_NEE_SPLIT < 64
    assert est.delta_chain == 4 and est.nee and est.tree_split == 4 and est.specular_nee == 1
    # a run with fewer NEE samples at a glint than the cap keeps its own in the pilot
    assert entrance_sampling.pilot_estimator(EstimatorOptions(nee_split=3)).nee_split == 3


def test_a_trace_does_not_depend_on_what_the_process_traced_before(wide_slab):
    """The kept tables are keyed by the estimator options too: the entrance pilot traces with them, so a
    table kept from another estimator set would give other numbers for the same seed."""
    from straylight.engine.runtime import runtime

    sc, src, mats = wide_slab
    other = TraceOptions(estimator=EstimatorOptions(nee=True, entrance_sampling=True, delta_chain=4))
    runtime().forget_tables()
    alone = trace(sc, src, 4_000, seed=9, materials=mats, options=ENTRANCE).detectors["det"].power_w
    runtime().forget_tables()
    trace(sc, src, 4_000, seed=9, materials=mats, options=other)
    after = trace(sc, src, 4_000, seed=9, materials=mats, options=ENTRANCE).detectors["det"].power_w
    assert after == alone


def _fake_pilot(bright: bool):
    """A run_batch whose rays 0, 1, 2, ... reach the detector with weight 1 each (``bright``: every ray)
    or only ray 0 (a dim point: one ray holds the light)."""
    calls = []

    def run_batch(pilot, first, stop, intersector):
        calls.append((first, stop))
        rays = np.arange(first * 1000, stop * 1000) if bright else np.array([0] if first == 0 else [], int)
        return {"paths": {"ray": rays, "power_w": np.ones(len(rays))}}

    return run_batch, calls


@pytest.mark.parametrize("bright", [True, False])
def test_the_pilot_stops_after_its_first_stage_when_it_has_seen_enough(wide_slab, bright):
    """A bright point's contributions have an effective sample size of thousands after the first stage:
    the pilot ends there; a dim point's run the whole pilot (each stage continues the same streams)."""
    from straylight.trace import make_spec

    sc, src, mats = wide_slab
    spec = make_spec(sc, src, 1_000, 5, mats, ENTRANCE)
    run_batch, calls = _fake_pilot(bright)
    table = entrance_sampling.build_table(spec, run_batch)
    first = entrance_sampling.PILOT_FIRST_RAYS // 1000
    if bright:
        assert calls == [(0, first)] and table.pilot_rays == entrance_sampling.PILOT_FIRST_RAYS
    else:
        assert calls == [(0, first), (first, entrance_sampling.PILOT_RAYS // 1000)]
        assert table.pilot_rays == entrance_sampling.PILOT_RAYS


def test_a_pilot_in_two_stages_learns_the_table_of_one(wide_slab, monkeypatch):
    """The stages trace the whole pilot's streams: without the early stop, two stages give the very table
    one stage of all the rays gives."""
    from straylight.engine.walk import run_batch
    from straylight.trace import make_spec

    sc, src, mats = wide_slab
    spec = make_spec(sc, src, 1_000, 5, mats, ENTRANCE)
    monkeypatch.setattr(entrance_sampling, "PILOT_ENOUGH_ESS", math.inf)
    monkeypatch.setattr(entrance_sampling, "PILOT_GUIDE_HITS", math.inf)  # the rest uniform, not guided
    monkeypatch.setattr(entrance_sampling, "PILOT_FIRST_RAYS", 2_000)
    staged = entrance_sampling.build_table(spec, run_batch, n_rays=6_000)
    monkeypatch.setattr(entrance_sampling, "PILOT_FIRST_RAYS", 6_000)
    whole = entrance_sampling.build_table(spec, run_batch, n_rays=6_000)
    assert staged.pilot_hits > 100 and staged.pilot_rays == whole.pilot_rays == 6_000
    np.testing.assert_array_equal(staged.prob, whole.prob)


def _thin_band(u):
    """A pilot contribution over the source's uniforms: a lit band 0.008 wide (half a cell of the 64 x 64 scale)
    and a dim half, as a lens's ghost over the entrance points."""
    band = np.abs(u[:, 0] - 0.3) < 0.004
    return np.where(band, 1.0 + u[:, 1], 0.0) + 1e-3 * (u[:, 1] > 0.5)


COARSE = {"grid": 64, "scales": (64, 16, 4)}


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_guided_stage_weighted_by_its_density_learns_the_table_closer(seed):
    """Rays drawn from a first table and weighted by 1 / p in their cells' means estimate the uniform
    measure's table: 1e4 uniform + 2e4 guided rays come closer to the table of 1e6 uniform rays (total
    variation distance) than 3e4 uniform rays do, and than the same rays counted as if uniform. On a 64 x 64
    table: the weighting does not depend on the grid, and 1e6 rays measure a 64 x 64 truth to well below the
    distances compared (~250 rays a cell; the default 256 x 256 would leave ~15)."""
    big = np.random.default_rng(99).random((1_000_000, 2))
    truth = table_from_contributions(big, _thin_band(big), **COARSE)
    rng = np.random.default_rng(seed)
    uni = rng.random((30_000, 2))
    first = table_from_contributions(uni[:10_000], _thin_band(uni[:10_000]), **COARSE)
    rest = rng.random((20_000, 2))
    rho = np.concatenate([np.ones(10_000), warp(first, rest)])
    u = np.concatenate([uni[:10_000], rest])

    def distance(table):
        return 0.5 * np.abs(table.prob - truth.prob).sum()

    guided = distance(table_from_contributions(u, _thin_band(u), rho=rho, **COARSE))
    assert guided < 0.75 * distance(table_from_contributions(uni, _thin_band(uni), **COARSE))
    assert guided < 0.9 * distance(table_from_contributions(u, _thin_band(u), **COARSE))


def test_the_rest_of_the_pilot_draws_from_the_first_stages_table_when_enough_rays_saw_light(wide_slab, monkeypatch):
    """A first stage with many lit rays but a low effective sample size guides the rest: the second
    call runs with entrance sampling on the first stage's table (own streams, the rest of the pilot)."""
    from straylight.trace import make_spec

    sc, src, mats = wide_slab
    spec = make_spec(sc, src, 1_000, 5, mats, ENTRANCE)
    monkeypatch.setattr(entrance_sampling, "PILOT_ENOUGH_ESS", math.inf)
    specs = []

    def run_batch(pilot, first, stop, intersector=None):
        specs.append(pilot)
        rays = np.arange(first * 1000, stop * 1000)
        return {"paths": {"ray": rays, "power_w": np.ones(len(rays))}}

    table = entrance_sampling.build_table(spec, run_batch)
    assert len(specs) == 2 and specs[0].entrance_table is None and not specs[0].options.estimator.entrance_sampling
    assert specs[1].options.estimator.entrance_sampling and specs[1].entrance_table is not None
    assert specs[1].chunk_offset == entrance_sampling.PILOT_CHUNK_OFFSET
    assert table.pilot_rays == entrance_sampling.PILOT_RAYS


@pytest.mark.parametrize("grid, defensive", [(256, 0.25), (16, 0.0), (12, 0.1)])
def test_the_compiled_warp_is_bit_identical_to_its_numpy_twin(grid, defensive):
    """entrance_sampling.warp (a guide table and one compiled pass) against warp_numpy (np.searchsorted):
    the same cells, uniforms and weight factors, bit for bit, on a peaked table (one bright cell among
    empty ones; without the defensive share some cells have probability 0 and equal CDF values), a grid
    whose G^2 is not a power of two, uniforms on cell edges, 0 and just below 1, and a strided view."""
    from straylight.engine.entrance_sampling import table_from_contributions, warp, warp_numpy

    rng = np.random.default_rng(grid)
    u = rng.random((20_000, 2))
    x = np.where(rng.random(len(u)) < 0.01, rng.random(len(u)), 0.0)
    x[:3] = 50.0  # the bright cell
    table = table_from_contributions(u, x, grid=grid, defensive=defensive, scales=(grid, 4))
    edges = np.concatenate([table.cdf[:50], table.cdf[-50:], [0.0, np.nextafter(1.0, 0.0)]])
    draws = np.concatenate([rng.random((30_000, 2)), np.stack([edges, rng.random(len(edges))], axis=1)])
    want = draws.copy()
    f_want = warp_numpy(table, want)
    got = draws.copy()
    np.testing.assert_array_equal(warp(table, got), f_want)
    np.testing.assert_array_equal(got, want)
    wide = np.zeros((len(draws), 5))
    wide[:, 1:3] = draws
    np.testing.assert_array_equal(warp(table, wide[:, 1:3]), f_want)  # a strided view, moved in place
    np.testing.assert_array_equal(wide[:, 1:3], want)


def test_the_rest_runs_the_eye_chains_and_the_first_stage_leaves_their_family_out(wide_slab, monkeypatch):
    """Given the run's eye table (asked for once, after the first stage, when the rest is guided), the rest runs
    the chains with it, their source connections not counted, and the table is learnt from the rest and the first
    stage's records outside the chains' family (``chain_family``; the first stage's table, which guides the rest,
    from all of them). The first stage runs without the chains, its records carrying the events chain_family
    reads. Without an eye table the rest is the pilot's own and every record counts."""
    from straylight.engine.reverse_chain import EyeTable
    from straylight.trace import make_spec

    sc, src, mats = wide_slab
    spec = make_spec(sc, src, 1_000, 5, mats, TraceOptions(estimator=EstimatorOptions(entrance_sampling=True,
                                                                                      reverse_chain=4)))
    monkeypatch.setattr(entrance_sampling, "PILOT_ENOUGH_ESS", math.inf)
    eye = EyeTable(tables=(None,), normals=np.zeros((1, 3)), pilot_eyes=1, pilot_hits=1, key_prob=np.ones(1), n_keys=1)
    learnt = []
    table_from = entrance_sampling.table_from_contributions

    def spied(u, x, *args, **kw):
        learnt.append(np.array(x))
        return table_from(u, x, *args, **kw)

    monkeypatch.setattr(entrance_sampling, "table_from_contributions", spied)
    n1 = entrance_sampling.PILOT_FIRST_RAYS

    def pilot(with_eyes):
        specs, asked = [], []
        learnt.clear()

        def run_batch(s, first, stop, intersector=None):
            specs.append(s)
            rays = np.arange(first * 1000, stop * 1000)
            family = rays % 3 == 0  # a third of the records are the chains' family (event code 1)
            return {"paths": {"ray": rays, "power_w": np.where(family, 50.0, 1.0),
                              "events": np.where(family, 1, 2)[:, None]}}

        def eye_table():
            asked.append(len(specs))
            return eye if with_eyes else None

        entrance_sampling.build_table(spec, run_batch, eye_table=eye_table, chain_family=lambda ev: ev[:, 0] == 1)
        return specs, asked

    specs, asked = pilot(True)
    assert asked == [1] and len(specs) == 2
    first, rest = specs
    assert first.options.estimator.reverse_chain == 0 and first.eye_table is None
    assert first.options.output.path_depth == entrance_sampling.PILOT_PATH_DEPTH
    assert rest.options.estimator.reverse_chain == 4 and not rest.eye_table.source_connections
    assert rest.eye_table.tables == eye.tables and rest.chunk_offset == entrance_sampling.PILOT_CHUNK_OFFSET
    guide, final = learnt
    family = np.arange(n1) % 3 == 0
    assert np.all(guide[family] == 50.0) and np.all(guide[~family] == 1.0)
    assert np.all(final[:n1][family] == 0.0) and np.all(final[:n1][~family] == 1.0)
    specs, asked = pilot(False)
    assert asked == [1] and specs[1].options.estimator.reverse_chain == 0 and specs[1].eye_table is None
    assert np.all(learnt[-1][:n1][family] == 50.0)
