"""What per-ray polarization costs, in one run (CPU time, ratios only).

    python benchmarks/polarization_cost.py [--rays N] [--repeats R]

Scene: the engine-golden mixed tube (tests/data/engine_golden/tube_mixed.toml: Lambertian wall
and vanes, two "glossy" vanes with a k_correlation lobe of index 1.5, an absorbing vane, a mirror
end plate), NEE on, traced in-process, interleaved, best of R (CPU seconds of this process):

  plain, hooks          glossy -> the Lambertian black: nothing polarizes; the code as it is
  plain, no hooks       the same with the polarization hooks of brdf_scatter and delta_reflection
                        replaced by "unpolarized" (what the engine did before): the pay-nothing check
  polarizing            the scene as is: the glossy vanes polarize what they scatter, rays carry
                        Stokes vectors through every later scatter and mirror
  polarizing, no hooks  the same with the hooks off (scatter leaves light unpolarized, as before)

Prints each CPU time and the ratios hooks / no hooks.
"""
import argparse
import time
from pathlib import Path

from straylight.engine.interactions import brdf_scatter, delta_reflection
from straylight.scene import load_scene
from straylight.trace import TraceOptions, trace

SCENE = Path(__file__).resolve().parents[1] / "tests" / "data" / "engine_golden" / "tube_mixed.toml"


def run(rs, materials, n, seed, hooks):
    saved = brdf_scatter.arriving, delta_reflection.active_state
    if not hooks:
        brdf_scatter.arriving = lambda *a: None
        delta_reflection.active_state = lambda *a: None
    try:
        c = time.process_time()
        res = trace(rs.scene, rs.sources, n, seed, materials=materials, options=TraceOptions())
        return time.process_time() - c, res
    finally:
        brdf_scatter.arriving, delta_reflection.active_state = saved


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rays", type=int, default=40_000)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    rs = load_scene(SCENE)
    plain = dict(rs.materials)
    plain["glossy"] = rs.materials["benchmark_black"]
    cases = {"plain, hooks": (plain, True), "plain, no hooks": (plain, False),
             "polarizing": (rs.materials, True), "polarizing, no hooks": (rs.materials, False)}
    run(rs, plain, 2000, 1, True)  # compile and warm up
    run(rs, rs.materials, 2000, 1, True)
    best = {k: float("inf") for k in cases}
    power = {}
    for _ in range(args.repeats):
        for name, (mats, hooks) in cases.items():
            t, res = run(rs, mats, args.rays, 3, hooks)
            best[name] = min(best[name], t)
            power[name] = res.detectors["detector"].power_w
    for name in cases:
        print(f"{name:22s} {best[name]:7.3f} CPU s   detector {power[name]:.10g} W")
    print(f"pay-nothing ratio (plain, hooks / no hooks):        x{best['plain, hooks'] / best['plain, no hooks']:.3f}")
    print(f"price of polarization (polarizing / no hooks):      x{best['polarizing'] / best['polarizing, no hooks']:.3f}")


if __name__ == "__main__":
    main()
