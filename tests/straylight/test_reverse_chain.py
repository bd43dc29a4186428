"""Reverse chains (straylight.engine.reverse_chain): eye chains from the detector through a glass slab,
joined to the source and to the walk's scatter vertices.

Scene: a 10 mm glass slab (n = 1.5, uncoated, two flat faces at z = 0 and -10) over a detector disk
(r = 4 mm at z = -20, facing up); above the slab a matte plate (z = 30, facing down) and a matte wall
(x = 30, facing -x), both lit by a collimated beam rising from below the plate. What reaches the
detector went plate (or wall) -> slab (T, T, or a ghost T R R T) -> detector: scatter seen only
through the glass, which next-event estimation cannot aim through. The analog walk (every estimator
off, another seed) is the independent reference; the chains must agree with it within 4 sigma, keep
the ledger exact, and be far more precise for the same rays.
"""
import math

import numpy as np
import pytest

from engine_helpers import disk_part, quad_part
from geometry.mesh import Scene
from materials import load_material
from materials.mueller import interface_mueller, rotate_stokes, s_vector
from straylight.engine.reverse_chain import unsupported
from straylight.sources import CollimatedDisk, PointSource
from straylight.trace import EstimatorOptions, OutputOptions, TraceOptions, make_spec, run_batch, \
    run_batch_reference, trace

N_GLASS = 1.5
ANALOG = EstimatorOptions(nee=False)
CHAINS = EstimatorOptions(nee=False, reverse_chain=4)


def _quad(name, p0, e1, e2, material=None, role="surface", n=6):
    return quad_part(name, p0, e1, e2, material, role, n)


@pytest.fixture(scope="module")
def slab_scene():
    top = _quad("top", (-60, -60, 0), (120, 0, 0), (0, 120, 0), "glass")  # normal +z: the air side
    bottom = _quad("bottom", (-60, -60, -10), (0, 120, 0), (120, 0, 0), "glass")  # normal -z: the air side
    plate = _quad("plate", (-40, -40, 30), (0, 80, 0), (80, 0, 0), "matte")  # normal -z: faces the slab
    wall = _quad("wall", (30, -40, 0.5), (0, 0, 29), (0, 80, 0), "matte")  # normal -x
    det = disk_part("det", -20.0, 1.5, 64, role="detector")
    d = np.array([math.sin(math.radians(35.0)), 0.0, math.cos(math.radians(35.0))])
    src = CollimatedDisk(center_mm=[-15.0, 0.0, 5.0], normal=d, direction=d, radius_mm=12.0)
    mats = {"glass": load_material({"components": [{"type": "dielectric", "n": N_GLASS}]}, "glass"),
            "matte": load_material({"components": [{"type": "lambertian", "rd": 0.6}]}, "matte")}
    return Scene((top, bottom, plate, wall, det)), src, mats


def _run(scene, n, seed, est, record_paths=False):
    sc, src, mats = scene
    return trace(sc, src, n, seed=seed, materials=mats,
                 options=TraceOptions(estimator=est, output=OutputOptions(record_paths=record_paths)))


def test_chains_agree_with_the_analog_walk(slab_scene):
    chains = _run(slab_scene, 20_000, 3, CHAINS)
    analog = _run(slab_scene, 400_000, 4, ANALOG)
    c, a = chains.detectors["det"], analog.detectors["det"]
    assert c.power_w > 0 and a.power_w > 0
    assert abs(c.power_w - a.power_w) <= 4 * math.hypot(c.stderr_w, a.stderr_w), (c, a)
    assert abs(chains.ledger["balance_residual_w"]) < 1e-9 * chains.emitted_w


def test_chains_with_the_split_trees_and_nee_agree_and_are_far_more_precise(slab_scene):
    """With NEE and delta_chain on as well: the trees and the chains share the runs after an end point
    by the balance heuristic. Per ray, the variance is at least 4x smaller than the analog walk's
    (measured: ~25x)."""
    n_on, n_analog = 20_000, 400_000
    both = _run(slab_scene, n_on, 5, EstimatorOptions(reverse_chain=4, delta_chain=4))
    analog = _run(slab_scene, n_analog, 4, ANALOG)
    b, a = both.detectors["det"], analog.detectors["det"]
    assert abs(b.power_w - a.power_w) <= 4 * math.hypot(b.stderr_w, a.stderr_w), (b, a)
    assert abs(both.ledger["balance_residual_w"]) < 1e-9 * both.emitted_w
    per_ray = (b.stderr_w / b.power_w) ** 2 * n_on
    per_ray_analog = (a.stderr_w / a.power_w) ** 2 * n_analog
    assert 4 * per_ray < per_ray_analog, (b, a)


@pytest.fixture(scope="module")
def analog_slab(slab_scene):
    return _run(slab_scene, 400_000, 4, ANALOG)


@pytest.mark.parametrize("k, r", [(7, 2), (4, 1)])
def test_chains_and_trees_with_a_reflection_limit_agree(slab_scene, analog_slab, k, r):
    """With the trees' reflection limit R (delta_chain_reflections, the default set's K = 7, R = 2): the
    chains follow at most R reflections too, the walk keeps the runs with more, and an eye path past
    the trees' R keeps its whole weight. R = 1 leaves the ghost T R R T to the walk."""
    res = _run(slab_scene, 20_000, 5, EstimatorOptions(reverse_chain=4, delta_chain=k, delta_chain_reflections=r))
    b, a = res.detectors["det"], analog_slab.detectors["det"]
    assert abs(b.power_w - a.power_w) <= 4 * math.hypot(b.stderr_w, a.stderr_w), (b, a)
    assert abs(res.ledger["balance_residual_w"]) < 1e-9 * res.emitted_w


def test_the_covector_carried_back_gives_the_forward_chain(rng=np.random.default_rng(11)):
    """(v_P)_0 from the detector back equals S0 at the detector of unpolarized light sent forward
    through the same interfaces and frame rotations (three random interfaces, random amplitudes)."""
    n = 50

    def unit(x):
        return x / np.linalg.norm(x, axis=1)[:, None]

    # a real chain: each interface's s is normal to its plane of incidence, so to the segments on
    # both sides of it; d[i] is the forward direction of the segment arriving at interface i
    d, frames = [unit(rng.normal(size=(n, 3)))], []
    for i in range(3):
        frames.append(s_vector(d[i], unit(rng.normal(size=(n, 3)))))
        nxt = rng.normal(size=(n, 3))
        d.append(unit(nxt - np.einsum("ij,ij->i", nxt, frames[i])[:, None] * frames[i]))
    amps = [(rng.normal(size=n) + 1j * rng.normal(size=n), rng.normal(size=n) + 1j * rng.normal(size=n))
            for _ in range(3)]
    # forward: unpolarized light leaves P; at interface i turn into its frame and apply M_i
    S = np.zeros((n, 4))
    S[:, 0] = 1.0
    e1 = frames[0]
    for i in range(3):
        S = rotate_stokes(S, e1, frames[i], d[i]) if i else S
        S = np.einsum("nij,nj->ni", interface_mueller(*amps[i]), S)
        e1 = frames[i]
    forward = S[:, 0]
    # backward, as the eye chain does: (1, 0, 0, 0) at the detector, M^T at each interface, the
    # inverse rotations between them (along the forward direction of each segment)
    v = np.zeros((n, 4))
    v[:, 0] = 1.0
    e1 = frames[2]
    for i in (2, 1, 0):
        v = rotate_stokes(v, e1, frames[i], d[i + 1]) if i != 2 else v
        v = np.einsum("nji,nj->ni", interface_mueller(*amps[i]), v)
        e1 = frames[i]
    np.testing.assert_allclose(v[:, 0], forward, rtol=1e-10, atol=1e-12)


def test_the_compiled_and_reference_walks_give_the_same_bits(slab_scene):
    sc, src, mats = slab_scene
    spec = make_spec(sc, src, 2_000, 7, mats, TraceOptions(estimator=EstimatorOptions(reverse_chain=4, delta_chain=4)))
    a, b = run_batch(spec, 0, 2), run_batch_reference(spec, 0, 2)
    np.testing.assert_array_equal(a["s1"], b["s1"])
    np.testing.assert_array_equal(a["s2"], b["s2"])


def test_path_records_name_the_chain(slab_scene):
    res = _run(slab_scene, 5_000, 6, CHAINS, record_paths=True)
    names = res.scene_part_names if hasattr(res, "scene_part_names") else None
    p = res.paths
    assert len(p.depth) > 0
    # every record ends on a chain that crossed the slab: its last events are slab faces
    sc = slab_scene[0]
    slab_parts = {sc.part_names.index("top"), sc.part_names.index("bottom")}
    last = p.events[np.arange(len(p.depth)), np.clip(p.depth - 1, 0, p.events.shape[1] - 1)] // 4
    assert set(np.unique(last)) <= slab_parts, names
    assert abs(p.power_w.sum() - res.detectors["det"].power_w) <= 1e-9 * res.detectors["det"].power_w


def test_the_plan_says_why_it_does_not_run(slab_scene):
    sc, _src, mats = slab_scene
    point = PointSource([0.0, 0.0, 20.0])
    spec = make_spec(sc, point, 100, 0, mats, TraceOptions(estimator=CHAINS))
    assert "collimated_disk" in unsupported(spec)
    res = trace(sc, point, 1_000, seed=0, materials=mats, options=TraceOptions(estimator=CHAINS))
    assert "reverse_chain" in dict(res.strategies.off)


def test_a_strategy_the_plan_turns_off_never_runs(slab_scene, monkeypatch):
    """The walk obeys the plan: with a point source the plan turns reverse_chain off though its switch is
    on, and the walk never asks it for a batch state (in trace(), and in a direct run_batch, where the
    walk resolves the plan itself); a spec whose plan runs nothing (strategies_on=()) runs nothing."""
    from dataclasses import replace

    from straylight.engine.strategies.reverse_chain import ReverseChainStrategy

    calls = []
    built = ReverseChainStrategy.batch_state

    def counted(self, ctx):
        calls.append(ctx.n_rays)
        return built(self, ctx)

    monkeypatch.setattr(ReverseChainStrategy, "batch_state", counted)
    sc, src, mats = slab_scene
    point = PointSource([0.0, 0.0, 20.0])
    res = trace(sc, point, 1_000, seed=0, materials=mats, options=TraceOptions(estimator=CHAINS))
    assert "reverse_chain" in dict(res.strategies.off)
    run_batch(make_spec(sc, point, 1_000, 0, mats, TraceOptions(estimator=CHAINS)), 0, 1)
    assert calls == []
    spec = make_spec(sc, src, 1_000, 0, mats, TraceOptions(estimator=CHAINS))
    run_batch(replace(spec, strategies_on=()), 0, 1)
    assert calls == []
    run_batch(spec, 0, 1)  # the probe counts where the plan runs it
    assert calls == [1_000]


def test_the_beam_point_maps_back_to_its_uniforms_and_the_table_density():
    """CollimatedDisk.uniforms_at inverts emit; entrance_sampling.density is the density warp gives."""
    from straylight.engine.entrance_sampling import density, table_from_contributions, warp

    src = CollimatedDisk(center_mm=[1.0, -2.0, 5.0], normal=[0.3, 0.0, 0.95], direction=[0.0, 0.0, -1.0],
                         radius_mm=4.0)
    rng = np.random.default_rng(3)
    u = rng.random((500, 2))
    origins, _ = src.emit(np.ascontiguousarray(np.hstack([u, rng.random((500, 2))])))
    np.testing.assert_allclose(src.uniforms_at(origins), u, atol=1e-9)
    table = table_from_contributions(rng.random((2000, 2)), rng.random(2000) ** 4)
    w = u.copy()
    factor = warp(table, w)
    np.testing.assert_allclose(density(table, w), 1.0 / factor, rtol=1e-12)


def test_the_eye_table_draws_where_the_pilot_saw_light_and_inverts_its_density(slab_scene):
    """The pilot's table (build_table): its density q at the eye directions it drew, recovered from the
    forward arrival directions alone (what the split trees' balance weights use), equals the density
    the draw reported; and it draws the chains that end lit more often than cosine directions do."""
    from straylight.engine import reverse_chain as rc
    from straylight.engine.runtime import runtime

    sc, src, mats = slab_scene
    spec = make_spec(sc, src, 1_000, 3, mats, TraceOptions(estimator=CHAINS))
    scene = runtime().scene(spec, None)
    table = rc.build_table(spec, scene, n_eyes=20_000)
    assert table is not None and table.pilot_hits > 0
    u = np.random.default_rng(5).random((4_000, 7))
    eyes = rc.EyeChains(4, np.array([True, True, False, False, False]), rc.scatter_ends(spec))
    plain = eyes.trace(spec, scene, u.copy(), None)
    guided = eyes.trace(spec, scene, u.copy(), table)
    q, drawn = guided[1], guided[2]
    # the arrival direction of each guided chain, from its drawn uniforms (the cosine map about the normal)
    local = np.stack([np.sqrt(drawn[:, 0]) * np.cos(2 * np.pi * drawn[:, 1]),
                      np.sqrt(drawn[:, 0]) * np.sin(2 * np.pi * drawn[:, 1]), np.sqrt(1 - drawn[:, 0])], axis=1)
    j, side = table.keys(u[:, 0])  # u0 picks the (detector, side) key by the table's key probabilities
    assert np.all(j == 0)
    nz = side[:, None] * table.normals[0][None, :]
    from straylight.sources import orthonormal_basis

    t, b = orthonormal_basis(nz)
    eye = local[:, :1] * t + local[:, 1:2] * b + local[:, 2:3] * nz
    np.testing.assert_allclose(table.density_of_arrival(0, -eye), q, rtol=1e-9)
    lit = [len(np.unique(rc.source_connection(spec, scene, ends)[0])) for ends, *_ in (plain, guided)]
    assert lit[1] > 1.5 * lit[0], lit


def test_chains_without_the_table_agree_too(slab_scene, monkeypatch):
    """The same agreement when the pilot gives no table (cosine eye directions)."""
    from straylight.engine import reverse_chain as rc

    monkeypatch.setattr(rc, "build_table", lambda spec, scene, n_eyes=0, detected_w=None: None)
    from straylight.engine.runtime import runtime

    runtime().forget_tables()
    chains = _run(slab_scene, 20_000, 7, EstimatorOptions(reverse_chain=4, delta_chain=4))
    runtime().forget_tables()
    analog = _run(slab_scene, 400_000, 4, ANALOG)
    c, a = chains.detectors["det"], analog.detectors["det"]
    assert abs(c.power_w - a.power_w) <= 4 * math.hypot(c.stderr_w, a.stderr_w), (c, a)


def test_the_eye_pilot_guides_its_rest_by_the_first_stage_and_ends_when_it_joins_nothing(slab_scene, monkeypatch):
    """The rest of the pilot draws its (detector, side) keys by the first stage's key probabilities: on
    the slab, whose light reaches the detector's front only, it joins more chains than the same number of
    chains of uniform keys (expected 1.7x: 5000 chains half on the front, 15000 at 0.95); a first stage
    that joins none ends the pilot there, without a table."""
    from straylight.engine import reverse_chain as rc
    from straylight.engine.runtime import runtime

    sc, src, mats = slab_scene
    spec = make_spec(sc, src, 1_000, 3, mats, TraceOptions(estimator=CHAINS))
    scene = runtime().scene(spec, None)
    monkeypatch.setattr(rc, "PILOT_FIRST_EYES", 5_000)
    staged = rc.build_table(spec, scene, n_eyes=20_000)
    monkeypatch.setattr(rc, "PILOT_FIRST_EYES", 20_000)
    whole = rc.build_table(spec, scene, n_eyes=20_000)
    assert staged.pilot_eyes == whole.pilot_eyes == 20_000
    assert staged.pilot_hits > 1.5 * whole.pilot_hits > 0, (staged.pilot_hits, whole.pilot_hits)
    traced = []

    def joins_nothing(*args):  # a pilot whose chains end on no lit point
        traced.append(len(args[2].ray))
        return np.zeros(0, np.int64), np.zeros(0), None, None

    monkeypatch.setattr(rc, "PILOT_FIRST_EYES", 5_000)
    monkeypatch.setattr(rc, "source_connection", joins_nothing)
    assert rc.build_table(spec, scene, n_eyes=20_000) is None and len(traced) == 1  # the first stage only


def test_the_keys_are_drawn_by_their_probabilities_and_fold_into_q():
    """EyeTable.keys picks (detector, side) keys by inverse CDF of key_prob (never a key of probability
    0), and q carries P_key n_keys: the chains' E[1 / (P_key n_keys)] over the keys is 1, as a uniform
    key choice's."""
    from straylight.engine.reverse_chain import EyeTable

    prob = np.array([0.7, 0.0, 0.3, 0.0])  # the front only counted (the back keys 0): detectors 0 and 1
    table = EyeTable(tables=(None,) * 4, normals=np.array([[0, 0, 1.0], [0, 0, 1.0]]), pilot_eyes=1, pilot_hits=1,
                     key_prob=prob, n_keys=2)
    u0 = np.random.default_rng(2).random(200_000)
    j, side = table.keys(u0)
    key = 2 * j + (side < 0)
    freq = np.bincount(key, minlength=4) / len(u0)
    np.testing.assert_allclose(freq, prob, atol=4e-3)
    assert freq[1] == freq[3] == 0.0
    q = table.warp(j, side, np.random.default_rng(3).random((len(u0), 2)))
    np.testing.assert_allclose(q, prob[key] * 2)
    assert abs(np.mean(1.0 / q) - 1.0) < 0.01


@pytest.mark.parametrize("facing, sides", [(1, "both"), (-1, "both"), (1, "front")])
def test_chains_agree_with_the_analog_walk_when_one_side_sees_the_light(slab_scene, facing, sides):
    """The light on one side only (the detector facing the slab: its front; turned over: its back). Both
    sides counted: the pilot gives the lit side all but the defensive share of the chains; the front only:
    the back keys get none. The estimate, whose q carries the side's share, still agrees with the analog
    walk."""
    from straylight.engine import reverse_chain as rc
    from straylight.engine.runtime import runtime

    sc, src, mats = slab_scene
    parts = list(sc.parts[:-1]) + [disk_part("det", -20.0, 1.5, 64, role="detector", facing=facing)]
    scene = Scene(tuple(parts))
    out = OutputOptions(detector_sides=sides)
    spec = make_spec(scene, src, 1_000, 7, mats, TraceOptions(estimator=CHAINS, output=out))
    table = rc.build_table(spec, runtime().scene(spec, None), n_eyes=20_000)
    lit = 0 if facing > 0 else 1
    if sides == "both":
        assert table.key_prob[lit] > 1.0 - rc.KEY_DEFENSIVE / 2 - 1e-3 and table.tables[1 - lit] is None
    else:
        assert table.key_prob[0] == 1.0 and table.key_prob[1] == 0.0 and table.n_keys == 1

    def run(n, seed, est):
        runtime().forget_tables()
        return trace(scene, src, n, seed=seed, materials=mats, options=TraceOptions(estimator=est, output=out))

    chains = run(20_000, 7, EstimatorOptions(reverse_chain=4, delta_chain=4))
    analog = run(400_000, 4, ANALOG)
    c, a = chains.detectors["det"], analog.detectors["det"]
    assert c.power_w > 0 and a.power_w > 0
    assert abs(c.power_w - a.power_w) <= 4 * math.hypot(c.stderr_w, a.stderr_w), (c, a)
    assert abs(chains.ledger["balance_residual_w"]) < 1e-9 * chains.emitted_w


# ---------------------------------------------------------------- where the chains pay (EYE_SHARE_OFF)


def test_the_verdict_turns_the_chains_off_only_below_the_share():
    """verdict: the chains' family power is the mean of the pilot's chain values; off (EyesOff) only when
    it is below EYE_SHARE_OFF x the entrance pilot's detected power, and never when that power is unknown."""
    from straylight.engine.reverse_chain import EYE_SHARE_OFF, EyesOff, verdict

    x = np.zeros(1000)
    x[:3] = [1.0, 0.5, 0.5]  # the family: 2 / 1000 = 2e-3 W
    off = verdict(x, 1000, 1.0, share_off=3e-3)
    assert isinstance(off, EyesOff) and off.family_w == pytest.approx(2e-3) and off.share == pytest.approx(2e-3)
    assert "0.002 of the detected power" in off.reason and "1000 chains" in off.reason
    assert verdict(x, 1000, 1.0, share_off=2e-3) is None  # at the share itself the chains run
    assert verdict(x, 1000, 0.5, share_off=3e-3) is None  # 4e-3 of a dimmer detector: they run
    assert verdict(x, 4000, 1.0, share_off=1e-3) is not None  # the same values over 4x the chains: 5e-4
    for unknown in (None, 0.0, -1.0, float("nan"), float("inf")):  # no detected power to weigh by: they run
        assert verdict(x, 1000, unknown) is None
    assert verdict(np.zeros(10), 10, 1.0) is not None  # a pilot that joined nothing, with light on the detector
    assert verdict(np.array([np.nan]), 1, 1.0) is None
    assert EYE_SHARE_OFF < 1e-2  # a family the walk is left with stays a small part of the error


def test_the_plan_turns_a_declining_strategy_off_with_its_reason():
    """without_declined: a strategy whose table declines moves to the plan's ``off`` with the reason, the
    others stay as they were (also in the plan the walk resolves for a spec without one)."""
    from types import SimpleNamespace

    from straylight.engine.plan import StrategyPlan, without_declined
    from straylight.engine.reverse_chain import EyesOff

    plan = StrategyPlan(("nee", "entrance", "reverse_chain"), (("target_mis", "no target parts"),))
    off = EyesOff(family_w=1e-12, detected_w=1e-6, pilot_eyes=50_000)
    turned = without_declined(plan, SimpleNamespace(eye_table=off))
    assert turned.on == ("nee", "entrance")
    assert dict(turned.off) == {"target_mis": "no target parts", "reverse_chain": off.reason}
    assert "reverse_chain off: the eye pilot's chains carried 1e-06 of the detected power" in turned.notes()[1]
    assert without_declined(plan, SimpleNamespace(eye_table=None)) == plan


def test_the_entrance_pilot_brings_its_batches_to_the_detected_power():
    """PilotPower: each batch's records summed and scaled by its spec's n_rays (start weight P / N), pooled by
    rays traced: two batches of 1000 and 2000 of 3000 rays holding 1 W and 4 W of records estimate 5 W."""
    from types import SimpleNamespace

    from straylight.engine.strategies.entrance import PilotPower
    from straylight.rng import CHUNK_RAYS

    sums = iter([1.0, 4.0, 0.0])
    counted = PilotPower(lambda spec, a, b, *rest: {"paths": {"power_w": np.array([next(sums), 0.0])}})
    assert counted.detected_w is None
    spec = SimpleNamespace(n_rays=3 * CHUNK_RAYS)
    counted(spec, 0, 1)
    assert counted.detected_w == pytest.approx(3.0)  # 1 W over a third of the rays
    counted(spec, 1, 3)
    assert counted.detected_w == pytest.approx(5.0)
    counted(spec, 3, 4)  # past n_rays: nothing traced, nothing pooled
    assert counted.detected_w == pytest.approx(5.0)


def test_the_eye_pilot_ends_at_its_first_stage_when_its_chains_carry_little(slab_scene, monkeypatch):
    """With the entrance pilot's detected power given: far above the chains' family, the pilot stops after
    its first stage with EyesOff; far below, it builds the table as before and keeps both powers on it;
    without it (None), the table as before."""
    from straylight.engine import reverse_chain as rc
    from straylight.engine.runtime import runtime

    sc, src, mats = slab_scene
    spec = make_spec(sc, src, 1_000, 3, mats, TraceOptions(estimator=CHAINS))
    scene = runtime().scene(spec, None)
    monkeypatch.setattr(rc, "PILOT_FIRST_EYES", 5_000)
    table = rc.build_table(spec, scene, n_eyes=20_000)
    assert isinstance(table, rc.EyeTable) and table.detected_w is None and table.family_w > 0
    traced = []
    trace_chains = rc.EyeChains.trace

    def counted(self, spec_, scene_, u, table_):
        traced.append(len(u))
        return trace_chains(self, spec_, scene_, u, table_)

    monkeypatch.setattr(rc.EyeChains, "trace", counted)
    off = rc.build_table(spec, scene, n_eyes=20_000, detected_w=1e6 * table.family_w)
    assert isinstance(off, rc.EyesOff) and off.pilot_eyes == 5_000 and traced == [5_000]
    assert off.share < rc.EYE_SHARE_OFF and off.family_w > off.scattered_w > 0  # the slab's wall lights the plate
    on = rc.build_table(spec, scene, n_eyes=20_000, detected_w=table.family_w)
    assert isinstance(on, rc.EyeTable) and on.detected_w == table.family_w and on.pilot_eyes == 20_000


def test_chains_turned_off_by_their_pilot_leave_the_walk_agreeing(slab_scene, analog_slab, monkeypatch):
    """Entrance sampling and the split trees with the chains asked for: on the slab their family is all
    the light and they run; with EYE_SHARE_OFF raised past any share the plan turns them off, says why,
    and the walk counts their family itself: the estimate agrees with the analog walk within 4 sigma and
    the ledger stays exact."""
    from straylight.engine import reverse_chain as rc
    from straylight.engine.runtime import runtime

    est = EstimatorOptions(nee=True, entrance_sampling=True, delta_chain=4, reverse_chain=4)
    runtime().forget_tables()
    kept = _run(slab_scene, 5_000, 8, est)
    assert "reverse_chain" in kept.strategies.on
    monkeypatch.setattr(rc, "EYE_SHARE_OFF", 1e9)
    runtime().forget_tables()
    try:
        res = _run(slab_scene, 20_000, 9, est)
    finally:
        runtime().forget_tables()  # the kept eye table holds this verdict
    why = dict(res.strategies.off).get("reverse_chain", "")
    assert "eye pilot's chains carried" in why, res.strategies
    b, a = res.detectors["det"], analog_slab.detectors["det"]
    assert b.power_w > 0
    assert abs(b.power_w - a.power_w) <= 4 * math.hypot(b.stderr_w, a.stderr_w), (b, a)
    assert abs(res.ledger["balance_residual_w"]) < 1e-9 * res.emitted_w


def _slab_pilot_chains(slab_scene, n):
    """The slab scene's spec, compiled scene, eye chains (K = 4) and the end points of ``n`` chains drawn
    on the eye pilot's streams, as the eye pilot traces them."""
    from straylight.engine import reverse_chain as rc
    from straylight.engine.runtime import runtime

    sc, src, mats = slab_scene
    spec = make_spec(sc, src, 1_000, 3, mats, TraceOptions(estimator=CHAINS))
    scene = runtime().scene(spec, None)
    eyes = rc.EyeChains(4, rc.parts_with(spec, rc.Capability.DELTA_CHAIN), rc.scatter_ends(spec))
    ends, _, _ = eyes.trace(spec, scene, rc.eye_uniforms(spec, 0, n // 1000, n, rc.PILOT_CHUNK_OFFSET), None)
    return spec, scene, eyes, ends


def test_the_once_scattered_light_agrees_with_the_walks_own_paths(slab_scene):
    """once_scattered (the guard the verdict adds where the source connections alone say off): from the
    eye chains' end points P on the plate and the wall, the light the beam scatters once before them
    (source -> A -> P -> slab -> detector, A and P matte). The analog walk's records of that family (events:
    two scatters on the matte parts, then only the slab's faces, at most 4 of them) are the independent
    reference: within 4 sigma (measured: 2.16e-5 +- 0.04e-5 W against 2.09e-5 +- 0.27e-5 W)."""
    from straylight.engine import reverse_chain as rc
    from straylight.engine.ray_batch import EVENT_SCATTER, EVENT_SPECULAR

    sc, src, mats = slab_scene
    n = 200_000
    spec, scene, eyes, ends = _slab_pilot_chains(slab_scene, n)
    x = rc.once_scattered(spec, scene, ends, n, eyes.splits, eyes.end_material, 0)
    pilot, pilot_err = x.mean(), x.std() / math.sqrt(n)
    walk = trace(sc, src, 1_000_000, seed=4, materials=mats,
                 options=TraceOptions(estimator=ANALOG, output=OutputOptions(record_paths=True, path_depth=8)))
    p = walk.paths
    names = list(p.part_names)
    events, depth = np.asarray(p.events), np.asarray(p.depth)
    matte = [names.index(m) * 4 + EVENT_SCATTER for m in ("plate", "wall")]
    faces = [names.index(f) * 4 + EVENT_SPECULAR for f in ("top", "bottom")]
    sel = np.isin(events[:, 0], matte) & np.isin(events[:, 1], matte) & (depth >= 3) & (depth <= 6)
    for c in range(2, events.shape[1]):
        sel &= (depth <= c) | np.isin(events[:, c], faces)
    y = np.bincount(np.asarray(p.ray)[sel], np.asarray(p.power_w)[sel], minlength=walk.n_rays)
    ref, ref_err = y.sum(), math.sqrt(float((y * y).sum() - y.sum() ** 2 / walk.n_rays))
    assert np.count_nonzero(x) > 100 and np.count_nonzero(y) > 20, (np.count_nonzero(x), np.count_nonzero(y))
    assert abs(pilot - ref) <= 4 * math.hypot(pilot_err, ref_err), (pilot, pilot_err, ref, ref_err)


def test_the_verdict_keeps_the_chains_where_the_once_scattered_light_carries_the_share(slab_scene, monkeypatch):
    """_judge: with a detected power between what the source connections alone and what they and the
    once-scattered light carry would turn off, the chains stay on; with the once-scattered light taken
    away (monkeypatched to nothing) the same power turns them off."""
    from straylight.engine import reverse_chain as rc

    n = 20_000
    spec, scene, eyes, ends = _slab_pilot_chains(slab_scene, n)
    g, raw = rc.source_connection(spec, scene, ends)[:2]
    x = np.bincount(ends.ray[g], weights=raw, minlength=n)
    scattered = rc.once_scattered(spec, scene, ends, n, eyes.splits, eyes.end_material, 0)
    assert scattered.sum() > 0
    # the source connections carry 1e-3 of it (off), with the once-scattered light 1e-3 x (1 + s / x) (on)
    detected = x.mean() / 1e-3
    monkeypatch.setattr(rc, "EYE_SHARE_OFF", 1e-3 * (1 + 0.5 * scattered.sum() / x.sum()))
    assert rc._judge(spec, scene, eyes, [x], [ends], detected) is None
    monkeypatch.setattr(rc, "once_scattered", lambda spec_, scene_, e, m, *rest: np.zeros(m))
    off = rc._judge(spec, scene, eyes, [x], [ends], detected)
    assert isinstance(off, rc.EyesOff) and off.scattered_w == 0.0


@pytest.mark.parametrize("k, r, absorbing", [(4, 0, False), (3, 1, True)])
def test_the_compiled_eye_chains_are_bit_identical_to_their_numpy_twins(slab_scene, monkeypatch, k, r, absorbing):
    """EyeChains.trace with its compiled passes (reverse_chain.start_rays, _onward_loop) against the numpy
    twins (start_rays_numpy, EyeChains._onward_numpy): every field of every end point, the same bits (an
    absorbing glass too: the bulk factor); and start_rays on random frames, normal incidence (the s
    vector's fallback) included."""
    from straylight.engine import reverse_chain as rc
    from straylight.engine.runtime import runtime

    sc, src, mats = slab_scene
    if absorbing:
        mats = dict(mats, glass=load_material({"components": [{"type": "dielectric", "n": N_GLASS,
                                                                "absorption_per_mm": 0.05}]}, "glass"))
    spec = make_spec(sc, src, 1_000, 5, mats, TraceOptions(estimator=CHAINS))
    scene = runtime().scene(spec, None)
    u = rc.eye_uniforms(spec, 0, 20, 20_000, rc.PILOT_CHUNK_OFFSET)
    got = {}
    for compiled in (True, False):
        monkeypatch.setattr(rc.EyeChains, "compiled", compiled)
        eyes = rc.EyeChains(k, rc.parts_with(spec, rc.Capability.DELTA_CHAIN), rc.scatter_ends(spec), r)
        got[compiled] = eyes.trace(spec, scene, u, None), eyes.shadow_rays
    (ends, q, drawn), shadows = got[True]
    (ends_np, q_np, drawn_np), shadows_np = got[False]
    assert len(ends.ray) > 100 and (ends.k > 1).any() and shadows == shadows_np
    for f in ("ray", "point", "normal", "part", "material", "omega", "beta", "detector", "z", "k", "codes", "refl", "q"):
        np.testing.assert_array_equal(getattr(ends, f), getattr(ends_np, f), err_msg=f)
    np.testing.assert_array_equal(q, q_np)
    np.testing.assert_array_equal(drawn, drawn_np)
    rng = np.random.default_rng(4)
    nz = rng.normal(size=(5000, 3))
    nz /= np.linalg.norm(nz, axis=1)[:, None]
    nz[:3] = [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]
    drawn = rng.random((5000, 2))
    drawn[:3, 0] = 0.0  # straight along nz: d x nz vanishes
    z = rng.normal(size=(5000, 3))
    for a, b in zip(rc.start_rays(drawn, nz, z, 2e-4), rc.start_rays_numpy(drawn, nz, z, 2e-4)):
        np.testing.assert_array_equal(a, b)


def test_the_forward_codes_reverse_each_rows_first_k_codes():
    """reverse_chain._forward_codes: the eye order's first k codes of each row, reversed, -1 padded."""
    from straylight.engine.reverse_chain import _forward_codes

    codes = np.array([[5, 9, 13, -1], [5, -1, -1, -1], [7, 11, 15, 19], [-1, -1, -1, -1]], dtype=np.int64)
    want = np.array([[13, 9, 5, -1], [5, -1, -1, -1], [19, 15, 11, 7], [-1, -1, -1, -1]], dtype=np.int64)
    np.testing.assert_array_equal(_forward_codes(codes, np.array([3, 1, 4, 0])), want)


def test_the_keys_are_np_searchsorted_of_the_key_cdf(rng=np.random.default_rng(8)):
    """EyeTable.keys (a count of the CDF values <= u0) names the key np.searchsorted(cdf, u0, side="right")
    names, on random key probabilities with zeros, at uniforms on the CDF's values and just below them."""
    from straylight.engine.reverse_chain import EyeTable

    for _ in range(100):
        n_keys = 2 * int(rng.integers(1, 5))
        prob = np.where(rng.random(n_keys) < 0.3, 0.0, rng.random(n_keys))
        prob[0] += 0.1
        table = EyeTable(tables=(None,) * n_keys, normals=np.zeros((n_keys // 2, 3)), pilot_eyes=1, pilot_hits=1,
                         key_prob=prob / prob.sum(), n_keys=n_keys)
        cdf = table.key_cdf
        inner = cdf[cdf < 1.0]
        u0 = np.concatenate([rng.random(2000), inner, np.nextafter(inner, 0.0), [0.0, np.nextafter(1.0, 0.0)]])
        want = np.minimum(np.searchsorted(cdf, u0, side="right"), n_keys - 1)
        j, side = table.keys(u0)
        np.testing.assert_array_equal(j, want // 2)
        np.testing.assert_array_equal(side, np.where(want % 2 == 1, -1.0, 1.0))


def test_the_chains_family_is_named_by_a_records_events(slab_scene):
    """chain_family (what the entrance pilot leaves out of its first stage where the run traces eye chains): a
    matte scatter lit first (P, or A then P) followed by interfaces only, at least one; not a path whose first
    scatter follows an interface, one with a scatter after the interfaces, or one with no interface."""
    from straylight.engine import reverse_chain as rc
    from straylight.engine.ray_batch import EVENT_SCATTER, EVENT_SPECULAR

    sc, src, mats = slab_scene
    spec = make_spec(sc, src, 1_000, 3, mats, TraceOptions(estimator=CHAINS))
    top, bottom, plate, wall = 0, 1, 2, 3  # the scene's part order

    def path(*events):
        row = [part * 4 + kind for part, kind in events]
        return row + [-1] * (6 - len(row))

    s, r = EVENT_SCATTER, EVENT_SPECULAR
    events = np.array([
        path((plate, s), (top, r), (bottom, r)),  # P -> slab -> detector
        path((wall, s), (plate, s), (top, r), (bottom, r), (top, r), (bottom, r)),  # A -> P -> the slab's ghost
        path((plate, s), (top, r), (bottom, r), (top, r), (bottom, r), (top, r)),  # interfaces as far as recorded
        path((plate, s)),  # no interface
        path((top, r), (plate, s), (top, r)),  # lit through the glass
        path((plate, s), (top, r), (wall, s), (top, r)),  # a scatter after the interfaces
        path((plate, s), (wall, s), (plate, s), (top, r)),  # scattered twice before P
    ])
    want = [True, True, True, False, False, False, False]
    assert rc.chain_family(spec, events).tolist() == want
    assert rc.chain_family(spec, np.zeros((0, 6), dtype=np.int16)).shape == (0,)


def test_chains_in_the_entrance_pilots_rest_leave_the_walk_agreeing(slab_scene, analog_slab, monkeypatch):
    """Where the run traces eye chains with a table, the entrance pilot's rest runs them too (the trees keep
    their balance share against them; their source connections are not counted) and its first stage counts
    only the records outside their family: the table is another density, the estimate still agrees with the
    analog walk within 4 sigma and the ledger stays exact."""
    from straylight.engine import entrance_sampling
    from straylight.engine.runtime import runtime

    monkeypatch.setattr(entrance_sampling, "PILOT_ENOUGH_ESS", math.inf)
    monkeypatch.setattr(entrance_sampling, "PILOT_GUIDE_HITS", 10)
    rests = []
    rest_of_pilot = entrance_sampling._rest_of_pilot

    def spied(pilot, opt, eye_table):
        rest, walk_share = rest_of_pilot(pilot, opt, eye_table)
        rests.append((rest, walk_share))
        return rest, walk_share

    monkeypatch.setattr(entrance_sampling, "_rest_of_pilot", spied)
    runtime().forget_tables()
    try:
        res = _run(slab_scene, 20_000, 12, EstimatorOptions(nee=True, entrance_sampling=True, delta_chain=4,
                                                             reverse_chain=4))
    finally:
        runtime().forget_tables()
    ((rest, walk_share),) = rests
    assert walk_share and rest.options.estimator.reverse_chain == 4
    assert rest.eye_table is not None and not rest.eye_table.source_connections
    assert "reverse_chain" in res.strategies.on and "entrance" in res.strategies.on
    b, a = res.detectors["det"], analog_slab.detectors["det"]
    assert b.power_w > 0
    assert abs(b.power_w - a.power_w) <= 4 * math.hypot(b.stderr_w, a.stderr_w), (b, a)
    assert abs(res.ledger["balance_residual_w"]) < 1e-9 * res.emitted_w
