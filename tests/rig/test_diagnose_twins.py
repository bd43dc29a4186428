"""Stage and arm offsets told apart (rig.diagnose.twins) on a scan from rig.synth's own ray geometry."""
import pytest

from rig.diagnose import Problem, fit_baseline
from rig.diagnose.params import Model
from rig.diagnose.twins import check_twins
from rig.effects import build_effect
from rig.points import compact_plan
from rig.synth import glossy_black, synth_scan


def test_wrong_offset_is_replaced_by_its_twin():
    """A stage offset of 0.3 deg with a 2e-3 /sr floor; the model given the *arm* offset that moves
    the peak alike (-0.6 deg) plus the floor: the check puts the stage offset in its place."""
    truth = [build_effect("angle_offset", offset_deg=0.3), build_effect("stray_background", level_per_sr=2e-3)]
    scan = synth_scan(glossy_black(), compact_plan(theta_i_deg=(10.0, 40.0, 70.0, 80.0)), truth, seed=2, n_samples=512)
    p = Problem(scan, holdout_theta_i_deg=[40.0])
    base = fit_baseline(p)
    vals = dict(base.model.values)
    vals.update({("arm_offset", "offset_deg"): -0.6, ("stray_background", "level_per_sr"): 2e-3})
    wrong = p.fit(Model(base.model.n_lobes, vals, ("arm_offset", "stray_background")), max_nfev=40)
    fit, selected, checks, confounded = check_twins(p, wrong, ["arm_offset", "stray_background"])
    assert selected == ["angle_offset", "stray_background"]
    assert checks[0]["verdict"].startswith("replaced") and checks[0]["delta_bic_alternative"] < -10
    assert fit.model.effect_params("angle_offset")["offset_deg"] == pytest.approx(0.3, rel=0.1)
    assert not confounded
    # and checked again from the right one, it is kept: the data tell them apart
    _, again, checks, _ = check_twins(p, fit, selected)
    assert again == selected and checks[0]["verdict"].startswith("told apart")
