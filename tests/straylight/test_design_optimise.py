"""The vane optimiser (straylight.design.optimise): never worse than its Freniere start on the CRN
objective, and the vane count is the construction's."""
from straylight.design import construct_vanes, model
from straylight.design.evaluate import log_objective, pst_points
from straylight.design.optimise import optimise_vanes
from straylight.execution import Execution


def test_optimiser_keeps_count_and_never_loses_to_its_start():
    built = construct_vanes(20, 80, 12, 0, 20, max_vanes=6)
    _, _, mats = model.coating("z302_sample_b")
    angles = [20.0, 25.0, 30.0]
    res = optimise_vanes(built.spec, mats, angles, rays=400, seed=3, max_evals=4,
                         bevels=((45.0, "back"),), execution=Execution(threads=1))
    assert len(res.z_mm) == len(built.vanes) > 0
    assert res.best_objective <= res.start_objective
    # the returned design re-traced with the same seed gives the objective the optimiser reported
    s = res.spec
    j, _ = log_objective(pst_points(s, [s.vane_at(z) for z in res.z_mm], mats, angles, 400, 3,
                                    execution=Execution(threads=1)))
    assert abs(j - res.best_objective) < 1e-9
