"""Reference baffled tube (shared/BENCHMARK.md) in optiland 0.6.3 non-sequential mode.

Run inside optiland's own venv (benchmarks/pst_vs_peers.py does this):

    python optiland_tube.py --angle-deg 30 --seconds 20

Analytic primitives only (annular planes and cylinder barrels; optiland's
triangle-mesh path lets scattered rays through, see BENCHMARK.md): every face
that light can reach is a ReflectiveComponent with reflectance 0.05 and a
Lambertian BSDF. Forward trace, optiland's own Russian roulette, up to 21
surface hits. The detector is a 70 x 70 mm absorbing irradiance detector just
below the end plate, so only light through the r = 35 hole reaches it. The
collimated beam (radius 60 mm, perpendicular to its direction) is centred on
the entrance, so the power crossing the entrance disk is
total_flux * pi 50^2 cos(a) / (pi 60^2).

The standard error comes from independent repeats (batch means over seeds).
Prints one JSON line: ratio, stderr, rays, seconds.
"""
import argparse
import json
import math
import time

import numpy as np
from optiland.coordinate_system import CoordinateSystem
from optiland.nonsequential.bsdf.lambertian import LambertianBSDF
from optiland.nonsequential.components import ReflectiveComponent
from optiland.nonsequential.components.geometry.analytic import (
    AnnularPlaneGeometry,
    CylindricalFrustumGeometry,
)
from optiland.nonsequential.detectors.configs import IrradianceDetectorConfig
from optiland.nonsequential.scene import NSQScene
from optiland.nonsequential.sources.base import Spectrum
from optiland.nonsequential.sources.configs import CollimatedSourceConfig

RHO = 0.05
R_BEAM = 60.0


def black(geometry, name):
    return ReflectiveComponent(CoordinateSystem(), geometry, RHO, bsdf=LambertianBSDF(1.0), name=name)


def build_scene(angle):
    scene = NSQScene()
    scene.add_component("wall_in", black(CylindricalFrustumGeometry(50.0, 50.0, 0.0, 300.0), "wall_in"))
    scene.add_component("wall_out", black(CylindricalFrustumGeometry(51.0, 51.0, 0.0, 300.0), "wall_out"))
    scene.add_component("rim", black(AnnularPlaneGeometry(50.0, 51.0, 300.0), "rim"))
    for k in range(1, 8):
        z = 40.0 * k
        scene.add_component(f"vane{k}_top", black(AnnularPlaneGeometry(35.0, 50.0, z + 0.5), f"vane{k}_top"))
        scene.add_component(f"vane{k}_bot", black(AnnularPlaneGeometry(35.0, 50.0, z - 0.5), f"vane{k}_bot"))
        scene.add_component(f"vane{k}_edge", black(CylindricalFrustumGeometry(35.0, 35.0, z - 0.5, z + 0.5), f"vane{k}_edge"))
    scene.add_component("end_plate", black(AnnularPlaneGeometry(35.0, 50.0, 0.0), "end_plate"))
    scene.add_detector("detector", CoordinateSystem(z=-0.001),
                       IrradianceDetectorConfig(width=70.0, height=70.0, num_pixels_x=8, num_pixels_y=8))
    # beam along (sin a, 0, -cos a): local +z rotated about y by pi - a; its centre line
    # passes through the entrance centre, starting at z = 310
    s = 10.0 / math.cos(angle)
    scene.add_source("beam", CoordinateSystem(x=-s * math.sin(angle), z=300.0 + 10.0, ry=math.pi - angle),
                     CollimatedSourceConfig(spectrum=Spectrum.monochromatic(0.532), total_flux=1.0,
                                            aperture_radius=R_BEAM))
    return scene


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--angle-deg", type=float, required=True)
    parser.add_argument("--seconds", type=float, default=20.0, help="approximate trace time budget")
    parser.add_argument("--rays-per-repeat", type=int, default=200_000)
    args = parser.parse_args()
    a = math.radians(args.angle_deg)
    t0 = time.perf_counter()
    c0 = time.process_time()
    scene = build_scene(a)
    entrance = (50.0 / R_BEAM) ** 2 * math.cos(a)
    values = []
    seed = 1
    while True:
        result = scene.trace(args.rays_per_repeat, max_depth=21, seed=seed)
        values.append(float(result.detectors["detector"].total_flux_float) / entrance)
        seed += 1
        if time.perf_counter() - t0 > args.seconds and len(values) >= 4:
            break
    seconds = time.perf_counter() - t0
    cpu_seconds = time.process_time() - c0
    v = np.array(values)
    print(json.dumps({"tracer": "optiland", "version": "0.6.3", "angle_deg": args.angle_deg,
                      "ratio": float(v.mean()), "stderr": float(v.std(ddof=1) / math.sqrt(len(v))),
                      "rays": int(len(v) * args.rays_per_repeat), "seconds": seconds, "cpu_seconds": cpu_seconds}))


if __name__ == "__main__":
    main()
