"""Runs of interfaces into a detector followed by splitting (TraceOptions.delta_chain,
straylight.engine.delta_chain: the lens's own ghosts).

Scene: a collimated beam meets a 10 mm thick uncoated glass slab (n = 1.5, two flat faces) at
45 deg; a small detector below the slab sits where only the two-reflection ghost lands
("top (T) -> bottom (R) -> top (R) -> bottom (T)": displaced 3 x 10 tan(theta_t) in x, the direct
beam 1 x and the next ghost 5 x, both off the detector). Its power is, from the Fresnel equations
(Born & Wolf, Principles of Optics, §1.5.2; the plane of incidence is the same at every face, so s
and p stay apart),

    P_det / P = 1/2 sum_{s,p} (1 - R)^2 R^2,   r_s = (cos i - n cos t) / (cos i + n cos t),
                                                r_p = (n cos i - cos t) / (n cos i + cos t).

The analog walk reaches the detector with probability ~R^2 per ray (a few hundred in 1e5); the
split tree follows it from every ray, so its estimate is the formula to rounding."""
import math

import numpy as np
import pytest

from engine_helpers import disk_part, window_scene
from geometry.mesh import Part, Scene
from materials import load_material
from straylight.sources import CollimatedDisk
from straylight.trace import EstimatorOptions, TraceError, TraceOptions, trace

N = 1.5
THICK_MM = 10.0
ANALOG = TraceOptions(estimator=EstimatorOptions(nee=False))
CHAIN = TraceOptions(estimator=EstimatorOptions(nee=False, delta_chain=4))


def _ghost_fraction():
    """The formula of the module docstring at 45 deg."""
    ci = math.cos(math.radians(45.0))
    st = math.sin(math.radians(45.0)) / N
    ct = math.sqrt(1.0 - st * st)
    rs = ((ci - N * ct) / (ci + N * ct)) ** 2
    rp = ((N * ci - ct) / (N * ci + ct)) ** 2
    return 0.5 * sum((1.0 - r) ** 2 * r ** 2 for r in (rs, rp))


@pytest.fixture(scope="module")
def slab():
    v_top = np.array([[-100.0, -100.0, 0.0], [100.0, -100.0, 0.0], [100.0, 100.0, 0.0], [-100.0, 100.0, 0.0]])
    top = Part("top", v_top, np.array([[0, 1, 2], [0, 2, 3]]), material="glass", role="surface")  # +z: air side
    bottom = Part("bottom", v_top - [0.0, 0.0, THICK_MM], np.array([[0, 2, 1], [0, 3, 2]]), material="glass",
                  role="surface")  # -z: air side
    shift = THICK_MM * math.tan(math.asin(math.sin(math.radians(45.0)) / N))
    det = disk_part("det", -20.0, 4.0, 64, role="detector")
    det = Part("det", det.vertices_mm + np.array([3 * shift + 10.0, 0.0, 0.0]), det.faces, role="detector")
    d = np.array([math.sqrt(0.5), 0.0, -math.sqrt(0.5)])
    src = CollimatedDisk(center_mm=[-20.0, 0.0, 20.0], normal=d, direction=d, radius_mm=2.0)
    mats = {"glass": load_material({"components": [{"type": "dielectric", "n": N}]}, "glass")}
    return Scene((top, bottom, det)), src, mats


def test_the_split_tree_gives_the_fresnel_ghost_and_the_analog_walk_agrees(slab):
    sc, src, mats = slab
    want = _ghost_fraction()
    chain = trace(sc, src, 2_000, seed=7, materials=mats, options=CHAIN)
    analog = trace(sc, src, 150_000, seed=8, materials=mats, options=ANALOG)
    c, a = chain.detectors["det"], analog.detectors["det"]
    assert c.power_w / chain.emitted_w == pytest.approx(want, rel=1e-9)
    assert abs(chain.ledger["balance_residual_w"]) < 1e-9
    assert a.power_w > 0
    assert abs(a.power_w / analog.emitted_w - want) <= 4 * a.stderr_w / analog.emitted_w, (a, want)


def test_a_tree_shorter_than_the_ghost_leaves_it_to_the_walk(slab):
    """With K = 3 the ghost (4 interfaces) is the walk's: same mean, the walk's noise."""
    sc, src, mats = slab
    short = trace(sc, src, 150_000, seed=9, materials=mats, options=TraceOptions(estimator=EstimatorOptions(nee=False, delta_chain=3)))
    s = short.detectors["det"]
    assert s.stderr_w > 0
    assert abs(s.power_w / short.emitted_w - _ghost_fraction()) <= 4 * s.stderr_w / short.emitted_w
    assert abs(short.ledger["balance_residual_w"]) < 1e-9


def test_delta_chain_and_reflection_split_are_not_both_on():
    with pytest.raises(TraceError, match="delta_chain"):
        EstimatorOptions(delta_chain=4, reflection_split=True)
    with pytest.raises(TraceError, match="delta_chain"):
        EstimatorOptions(delta_chain=-1)


def test_the_trees_on_exact_surfaces_give_the_ghost_table_of_a_window():
    """The window of tests/straylight/test_ghosts.py (analytic planes, normal incidence, R = 0.04):
    the split trees' path records group into the nominal image (1 - R)^2 and the two-bounce ghost
    (1 - R)^2 R^2 (Born & Wolf §7.6.1), each to rounding from 2000 rays (the analog walk needs 4e5
    rays for a few per cent on the ghost)."""
    from straylight.analyses.ghosts import ghost_table
    from straylight.trace import OutputOptions

    scene, src, mats = window_scene()
    res = trace(scene, [src], 2_000, seed=3, materials=mats,
                options=TraceOptions(estimator=EstimatorOptions(nee=False, delta_chain=4),
                                     output=OutputOptions(record_paths=True)))
    table = ghost_table(res.paths, "det", res.detectors["det"].power_w)
    R = 0.04
    nominal, ghost = table.rows[0], table.rows[1]
    assert nominal.sequence == "source -> top -> bottom -> det"
    assert nominal.power_w == pytest.approx((1 - R) ** 2, rel=1e-9)
    assert ghost.kind == "two-bounce ghost" and ghost.surfaces == "bottom then top"
    assert ghost.power_w == pytest.approx((1 - R) ** 2 * R ** 2, rel=1e-9)
    assert abs(res.ledger["balance_residual_w"]) < 1e-9


@pytest.mark.parametrize("record_paths", [False, True])
def test_the_compiled_children_are_bit_identical_to_their_numpy_twin(record_paths):
    """DeltaChains._children (one compiled pass) against delta_chain.children_numpy on random branches:
    polarized Stokes vectors, complex amplitudes, zero and negative weights, rows at the reflection cap R,
    and codes narrower than the interface count (widened), with and without branches carried past their hits;
    every field bit for bit, signed zeros too."""
    from types import SimpleNamespace

    from straylight.engine.delta_chain import Branches, DeltaChains, children_numpy

    rng = np.random.default_rng(3)
    n_src, n = 50, 40
    unit = lambda a: a / np.linalg.norm(a, axis=1)[:, None]  # noqa: E731
    k = rng.integers(0, 10, n_src)
    src = Branches(rng.integers(0, 1000, n_src), unit(rng.normal(size=(n_src, 3))), unit(rng.normal(size=(n_src, 3))),
                   np.where(rng.random(n_src) < 0.2, 0.0, rng.random(n_src)), rng.normal(size=(n_src, 4)),
                   unit(rng.normal(size=(n_src, 3))), k, rng.integers(0, 5, n_src),
                   rng.integers(0, 2**63, n_src, dtype=np.uint64), rng.integers(-1, 30, (n_src, 8)),
                   rng.integers(0, 3, n_src), rng.integers(-1, 9, n_src))
    sel = rng.integers(0, n_src, n)
    facing = unit(rng.normal(size=(n, 3)))
    d = -facing + 0.5 * unit(rng.normal(size=(n, 3)))
    d = unit(d)
    at, s = rng.normal(size=(n, 3)), unit(rng.normal(size=(n, 3)))
    S = np.column_stack([np.ones(n), rng.uniform(-1, 1, (n, 3)) / 2])
    S[::7, 2:] = 0.0
    amp = lambda: rng.normal(size=n) + 1j * rng.normal(size=n)  # noqa: E731
    fresnel = (amp(), amp(), amp(), amp(), rng.random(n), rng.uniform(0.6, 1.5, n), rng.uniform(0.5, 1.0, n))
    fresnel[0][::5] = 0.0
    part = rng.integers(0, 6, n)
    chains = DeltaChains(8, 12, max_reflections=2)
    event = SimpleNamespace(settings=SimpleNamespace(record_paths=record_paths, eps_mm=1e-4))
    carry = (rng.integers(0, n_src, 9), rng.normal(size=(9, 3)), rng.integers(0, 6, 9))  # passing their hits
    no_rows = np.zeros(0, np.int64)
    cases = [((sel, at, d, part, facing, s, S, fresnel), None), ((sel, at, d, part, facing, s, S, fresnel), carry),
             ((no_rows, at[:0], d[:0], part[:0], facing[:0], s[:0], S[:0], tuple(x[:0] for x in fresnel)), carry)]
    for args, c in cases:
        got = chains._children(event, src, *args, carry=c)
        want = children_numpy(src, *args, 2e-4, 2, record_paths, carry=c)
        assert want is not None and len(want.w) >= 9
        if len(args[0]):
            assert len(want.w) > n // 2 and want.codes.shape[1] > 8  # both branches, widened codes
        for f in Branches.FIELDS:
            a, b = np.asarray(getattr(got, f)), np.asarray(getattr(want, f))
            assert a.dtype == b.dtype and a.shape == b.shape, f
            assert a.tobytes() == b.tobytes(), f
    assert chains._children(event, src, *cases[2][0]) is None


def test_the_compiled_incidence_frames_are_bit_identical_to_s_vector_and_rotate_stokes():
    """delta_chain.incidence_frames (one compiled pass) against materials.mueller's s_vector and rotate_stokes
    on the gathered rows, at oblique and normal incidence (the fallback s vectors d x x and d x y)."""
    from straylight.engine.delta_chain import incidence_frames, incidence_frames_numpy

    rng = np.random.default_rng(5)
    n_src, n = 40, 60
    unit = lambda a: a / np.linalg.norm(a, axis=1)[:, None]  # noqa: E731
    S = np.column_stack([np.ones(n_src), rng.uniform(-0.5, 0.5, (n_src, 3))])
    e1 = unit(rng.normal(size=(n_src, 3)))
    sel = rng.integers(0, n_src, n)
    facing = unit(rng.normal(size=(n, 3)))
    d = unit(-facing + 0.4 * unit(rng.normal(size=(n, 3))))
    d[:4] = -facing[:4]  # normal incidence
    d[4], facing[4] = [1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]  # d x x vanishes too
    got, want = incidence_frames(S, e1, sel, d, facing), incidence_frames_numpy(S, e1, sel, d, facing)
    for a, b in zip(got, want):
        assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
