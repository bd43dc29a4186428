"""Ghost analysis of a window: the two-bounce ghost of its two surfaces, grouped from path records.

Reference: incoherent plate (Born & Wolf §7.6.1), normal incidence, R = ((n-1)/(n+1))^2: the direct
transmission carries (1-R)^2, the two-bounce ghost (reflect at the bottom, then the top) (1-R)^2 R^2,
the next ghost (1-R)^2 R^4.
"""
from engine_helpers import window_scene
from straylight.analyses.ghosts import ghost_table, two_bounce_pair
from straylight.trace import EstimatorOptions, OutputOptions, TraceOptions, trace


def test_two_bounce_pattern():
    n = ("lens1_a", "lens1_b", "lens2_a", "lens2_b")
    assert two_bounce_pair(("lens1_a", "lens1_b", "lens2_a", "lens1_b", "lens2_a", "lens2_b"), n) == ("lens1_b", "lens2_a")
    assert two_bounce_pair(("lens1_a", "lens1_b", "lens1_a", "lens1_b", "lens2_a", "lens2_b"), n) == ("lens1_a", "lens1_b")
    assert two_bounce_pair(n, n) is None


def test_window_ghost_power():
    scene, src, mats = window_scene()
    res = trace(scene, [src], 400_000, seed=3, materials=mats,
                options=TraceOptions(estimator=EstimatorOptions(nee=False), output=OutputOptions(record_paths=True)))
    table = ghost_table(res.paths, "det", res.detectors["det"].power_w)
    R = 0.04
    nominal, ghost = table.rows[0], table.rows[1]
    assert nominal.kind == "nominal" and nominal.sequence == "source -> top -> bottom -> det"
    assert abs(nominal.power_w - (1 - R) ** 2) < 4 * nominal.stderr_w
    assert ghost.kind == "two-bounce ghost" and ghost.surfaces == "bottom then top"
    assert ghost.power_w > 0 and abs(ghost.power_w - (1 - R) ** 2 * R**2) < 4 * ghost.stderr_w
