"""Plans as arrays live with the points (rig/points.py); the diagnosis benchmark in benchmarks/."""
import subprocess
import sys
from pathlib import Path

import numpy as np

import rig.synth
from rig.points import compact_plan, paper_plan, paper_theta_r_deg, score_plan

ROOT = Path(__file__).resolve().parents[2]


def test_paper_plan_is_the_paper_grid_plus_a_backscatter_wing():
    """At theta_i = 40 deg, counted by hand from the zone table of rig/points.py: core 21, shoulder
    20, near 10, wing d = -10..-40 and +10..+45 (15), so 66 on the specular side (0..85 deg); the
    backscatter side every 5 deg from 5 to 85 less the one within 3 deg of the beam (-40): 16."""
    ti, tr, pol = paper_plan(theta_i_deg=(40.0,), polarizations=("s", "p"))
    assert len(ti) == 2 * 82 and set(ti) == {40.0}
    for p in "sp":
        curve = tr[pol == p]
        assert np.array_equal(curve[curve >= 0], paper_theta_r_deg(40.0))
        assert np.array_equal(curve[curve < 0], -np.array([5.0 * k for k in range(1, 18) if k != 8])[::-1])


def test_compact_and_score_plans():
    """compact_plan at 10 deg, by hand: 0.1 deg steps 9.5..10.5 (11), 0.5 deg steps 7..13 (10 more),
    5 deg steps -85..85 (34 more: 10 is there already), less -10 (the retro-reflection): 54."""
    ti, tr, pol = compact_plan(theta_i_deg=(10.0,), polarizations=("s",))
    assert len(tr) == 54 and -10.0 not in tr and set(pol) == {"s"}
    ti, tr, pol = score_plan()
    assert sorted(set(ti)) == [10.0, 25.0, 40.0, 55.0, 70.0, 80.0] and set(pol) == {"s", "p"}


def test_synth_holds_no_plans_and_no_benchmark():
    for name in ("make_plan", "paper_plan", "score_plan", "compact_plan", "bench", "score_table", "default_cases"):
        assert not hasattr(rig.synth, name) or getattr(rig.synth, name).__module__ != "rig.synth", name
    assert "__main__" not in (ROOT / "rig" / "synth.py").read_text()


def test_diagnose_benchmark_script_parses_its_arguments():
    run = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "diagnose_score.py"), "--help"],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0 and "--bench" in run.stdout and "--score-table" in run.stdout
    run = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "diagnose_score.py")],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and "give --bench and/or --score-table" in run.stderr
