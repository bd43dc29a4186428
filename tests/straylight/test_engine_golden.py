"""Same seed, same numbers: the engine reproduces the results recorded BEFORE the engine was split
into stages (commit c2b77b3 of main), to 1e-15 relative.

These are regression values, not physics: they pin the refactor (and any later speed work) to the
exact random walk of the engine they were recorded with. Physics is checked elsewhere
(tests/validation, test_engine_core). Inputs in tests/data/engine_golden/: the reference tube
(`straylight geometry build tube --tolerance-mm 0.2`) lit 20 deg off axis, and a variant with every
kind of part (two materials, a mirror, an absorber, two sources). Recorded with
``python tests/straylight/test_engine_golden.py --record`` (only ever re-record on purpose, for a
change that is meant to change the numbers, and say so in the commit).
"""
from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import pytest

GOLDEN = Path(__file__).resolve().parents[1] / "data" / "engine_golden"
# the ledger's sums over parts and rays are numpy reductions, whose order of additions numpy's versions change:
# numpy 2.4.6 (a fresh install, 2026-12-07) reads tube_mixed_seed3's roulette_w and nee_exchange_w 2e-15 apart
# from the recorded values; an engine change moves them by far more than this
REL = 1e-13

# straylight trace SCENE ARGS -> golden JSON
CLI_CASES = {
    "tube_seed7": ["tube.toml", "--rays", "40000", "--seed", "7"],
    "tube_seed7_no_nee": ["tube.toml", "--rays", "40000", "--seed", "7", "--no-nee"],
    "tube_mixed_seed3": ["tube_mixed.toml", "--rays", "40000", "--seed", "3"],
}
# straylight rig twin ARGS -> golden JSON (the twin's own numbers are compared; the fast model is not the engine)
TWIN_CASES = {
    "rig_twin_seed5": ["--sample", "z302_sample_b", "--theta-i-deg", "20", "--theta-r-deg", "-10", "20", "45",
                       "--polarization", "s", "u", "--rays", "4000", "--seed", "5"],
    "rig_twin_mirror_seed2": ["--sample", "mirror:0.9", "--theta-i-deg", "30", "--theta-r-deg", "30", "31",
                              "--rays", "3000", "--seed", "2"],
}
TWIN_KEYS = ("theta_i_deg", "theta_r_deg", "polarization", "twin_brdf_per_sr", "twin_stderr_per_sr", "estimator")
# trace(...) through the Python API: options the command line does not reach
API_CASES = {
    "api_mixed_paths": ("tube_mixed.toml", 30000, 11, dict(
        estimator=dict(nee_samples=2, rr_threshold=0.02),
        output=dict(record_paths=True, detector_sides="front", map_bins=(8, 8)), physics=dict(max_events=7))),
    "api_mixed_target": ("tube_mixed.toml", 20000, 12, dict(
        estimator=dict(target_parts=("detector",), target_fraction=0.3), output=dict(map_bins=(4, 6)))),
    "api_tube_vertex_paths": ("tube.toml", 30000, 13, dict(
        estimator=dict(first_vertex_sampling=True), output=dict(record_paths=True, path_depth=3, map_bins=(5, 5)))),
}


#: top-level keys that describe the run, not its numbers, added after the goldens were recorded: not compared
#: (``strategies``: which requested strategies ran, straylight.engine.plan)
RUN_DESCRIPTION_KEYS = {"strategies"}


def _mismatches(got, want, where="$"):
    """Paths where ``got`` differs from ``want`` (floats: more than REL relative)."""
    if where == "$" and isinstance(got, dict):
        got = {k: v for k, v in got.items() if k not in RUN_DESCRIPTION_KEYS or k in want}
    if isinstance(want, dict):
        if not isinstance(got, dict) or set(got) != set(want):
            return [f"{where}: keys {sorted(got) if isinstance(got, dict) else got!r} != {sorted(want)}"]
        return [m for k in want for m in _mismatches(got[k], want[k], f"{where}.{k}")]
    if isinstance(want, list):
        if not isinstance(got, list) or len(got) != len(want):
            return [f"{where}: length {len(got) if isinstance(got, list) else got!r} != {len(want)}"]
        return [m for k, (g, w) in enumerate(zip(got, want)) for m in _mismatches(g, w, f"{where}[{k}]")]
    if isinstance(want, float) and isinstance(got, (int, float)) and not isinstance(got, bool):
        if got == want or math.isclose(got, want, rel_tol=REL, abs_tol=0.0):
            return []
        return [f"{where}: {got!r} != {want!r}"]
    return [] if got == want else [f"{where}: {got!r} != {want!r}"]


def api_summary(res) -> dict:
    """to_json_dict plus what it leaves out: incident, first hits, irradiance maps, path groups."""
    out = res.to_json_dict()
    out["incident"] = {k: v.to_dict() for k, v in res.incident.items()}
    out["first_hit"] = {k: v.to_dict() for k, v in res.first_hit.items()}
    out["maps"] = {k: {"power_w": m.power_w.ravel().tolist(), "stderr_w": m.stderr_w.ravel().tolist()}
                   for k, m in res.maps.items()}
    if res.paths is not None:
        out["path_groups"] = [{"key": str(g.key), "events": [list(e) for e in g.events], "power_w": g.power_w,
                               "stderr_w": g.stderr_w, "n_records": g.n_records} for g in res.paths.group()[:25]]
        out["n_path_records"] = len(res.paths)
    return out


def run_cli(name, out_dir) -> dict:
    from straylight.cli.main import main

    out = Path(out_dir) / f"{name}.json"
    args = CLI_CASES[name]
    assert main(["trace", str(GOLDEN / args[0]), *args[1:], "--json", str(out)]) == 0
    return json.loads(out.read_text())


def run_twin(name, out_dir) -> dict:
    from straylight.cli.main import main

    out = Path(out_dir) / f"{name}.json"
    assert main(["rig", "twin", *TWIN_CASES[name], "--json", str(out)]) == 0
    return json.loads(out.read_text())


def run_api(name) -> dict:
    from straylight.scene import load_scene
    from straylight.trace import EstimatorOptions, OutputOptions, PhysicsOptions, TraceOptions, trace

    scene, n, seed, groups = API_CASES[name]  # the options by group
    rs = load_scene(GOLDEN / scene)
    opts = TraceOptions(estimator=EstimatorOptions(**groups.get("estimator", {})),
                        output=OutputOptions(**groups.get("output", {})),
                        physics=PhysicsOptions(**groups.get("physics", {})))
    return api_summary(trace(rs.scene, rs.sources, n, seed, materials=rs.materials, options=opts))


def _twin_numbers(doc):
    return [{k: p[k] for k in TWIN_KEYS} for p in doc["points"]]


@pytest.mark.parametrize("name", sorted(CLI_CASES))
def test_trace_json_as_recorded(name, tmp_path):
    want = json.loads((GOLDEN / f"{name}.json").read_text())
    bad = _mismatches(run_cli(name, tmp_path), want)
    assert not bad, f"{name}: {len(bad)} differences, first: " + "; ".join(bad[:5])


@pytest.mark.parametrize("name", sorted(TWIN_CASES))
def test_rig_twin_as_recorded(name, tmp_path):
    want = json.loads((GOLDEN / f"{name}.json").read_text())
    got = run_twin(name, tmp_path)
    assert got["n_rays_per_point"] == want["n_rays_per_point"] and got["seed"] == want["seed"]
    bad = _mismatches(_twin_numbers(got), _twin_numbers(want))
    assert not bad, f"{name}: {len(bad)} differences, first: " + "; ".join(bad[:5])


@pytest.mark.parametrize("name", sorted(API_CASES))
def test_trace_api_as_recorded(name):
    want = json.loads((GOLDEN / f"{name}.json").read_text())
    bad = _mismatches(run_api(name), want)
    assert not bad, f"{name}: {len(bad)} differences, first: " + "; ".join(bad[:5])


def test_mismatch_finder_sees_a_last_bit_change():
    """The comparison is not vacuous: one ulp off is within 1e-15, three orders more is not."""
    x = 0.07522096299981577
    assert not _mismatches({"a": [math.nextafter(x, 1.0)]}, {"a": [x]})
    assert _mismatches({"a": [x * (1 + 1e-12)]}, {"a": [x]})
    assert _mismatches({"a": 1}, {"a": 2}) and _mismatches({"a": 1}, {"b": 1})


if __name__ == "__main__" and "--record" in sys.argv:
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        docs = {**{n: run_cli(n, tmp) for n in CLI_CASES}, **{n: run_twin(n, tmp) for n in TWIN_CASES},
                **{n: run_api(n) for n in API_CASES}}
    for n, doc in docs.items():
        (GOLDEN / f"{n}.json").write_text(json.dumps(doc, indent=1 if n in API_CASES else 2) + "\n")
        print("recorded", n)
