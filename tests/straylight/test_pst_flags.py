"""The ``flags`` of a PST point (pst.csv's last column, each pst.json point): what a mission simulator
reads to know which points to trust (docs/notebook.md, "PST files for other programs")."""
from straylight.analyses.types import FLAGS, point_flags


def test_a_sound_point_has_no_flag():
    assert point_flags({"pst": 1e-5, "vov": 0.01}) == ""
    assert point_flags({"pst": 1e-5, "vov": 0.01, "stop_reason": "target"}) == ""


def test_each_flag_and_their_order():
    assert point_flags({"pst": 0.0, "vov": float("nan")}) == "zero"
    assert point_flags({"pst": 2e-6, "vov": 0.4}) == "unreliable_error"
    assert point_flags({"pst": 2e-6, "vov": 0.05, "stop_reason": "max_rays"}) == "target_not_reached"
    assert point_flags({"pst": 0.0, "vov": 0.5, "stop_reason": "max_seconds"}) == "zero;unreliable_error;target_not_reached"
    assert set(FLAGS) == {"zero", "unreliable_error", "target_not_reached"}


def test_a_negligible_error_bar_is_not_flagged_for_its_vov():
    """A point nearly all computed (direct_area: PST 1.0 +- 1.8e-8 on an exact-walled tube on axis, the rare
    scatter around it VOV 1): even a thousand times larger its error would be under 1 %, so no flag; an error of
    1e-4 of the point with the same VOV is flagged."""
    assert point_flags({"pst": 1.0, "pst_stderr": 1.8e-8, "vov": 1.0, "stop_reason": "target"}) == ""
    assert point_flags({"pst": 1.0, "pst_stderr": 1e-4, "vov": 1.0, "stop_reason": "target"}) == "unreliable_error"
