"""Reference baffled tube (shared/BENCHMARK.md) in raysect 0.9.1, backward by reciprocity.

Run inside raysect's own venv (benchmarks/pst_vs_peers.py does this):

    python raysect_tube.py --angle-deg 30 --seconds 20

raysect traces from observers to emitters, and a collimated source cannot be hit
by a backward ray. Reciprocity swaps the roles: the detector disk becomes a
Lambertian emitter of radiance L, and an orthographic camera looks down the
tube along the beam direction. The radiance it sees at a point x of the beam
cross-section is L * T(x), with T(x) the probability that a forward photon
starting at x reaches the detector. So

    ratio(a) = sum_pixels(L_pix) * A_pix / (L * A_entrance * cos a).

Scene in metres (raysect's epsilons assume metre-sized scenes); importance
sampling toward the detector is on (material importance = 1). One core
(SerialEngine). Prints one JSON line: ratio, stderr, rays, seconds.
"""
import argparse
import json
import math
import time

import numpy as np
from raysect.core import Point3D, Vector3D, rotate_basis, translate
from raysect.core.workflow import SerialEngine
from raysect.optical import ConstantSF, World
from raysect.optical.material import Lambert, UniformSurfaceEmitter
from raysect.optical.observer import OrthographicCamera, RadiancePipeline2D
from raysect.primitive import Cylinder, Subtract, Union

MM = 1e-3
R_IN, R_OUT, LENGTH = 50 * MM, 51 * MM, 300 * MM
VANE_R, VANE_T = 35 * MM, 1 * MM
VANE_Z = [40 * MM * k for k in range(1, 8)]
RHO = 0.05
EPS = 1e-6


def annulus(r_in, r_out, z0, z1):
    """Solid annulus r_in..r_out, z0..z1, as a CSG difference of two cylinders."""
    outer = Cylinder(r_out, z1 - z0, transform=translate(0, 0, z0))
    inner = Cylinder(r_in, z1 - z0 + 2 * EPS, transform=translate(0, 0, z0 - EPS))
    return Subtract(outer, inner)


def build_world():
    world = World()
    solid = annulus(R_IN, R_OUT, 0.0, LENGTH)
    for z in VANE_Z:
        # the vane overlaps the wall by 0.5 mm so the union has no seam
        solid = Union(solid, annulus(VANE_R, R_IN + 0.5 * MM, z - VANE_T / 2, z + VANE_T / 2))
    solid = Union(solid, annulus(VANE_R, R_OUT, -1 * MM, 0.0))
    solid.parent = world
    solid.material = Lambert(ConstantSF(RHO))
    emitter = UniformSurfaceEmitter(ConstantSF(1.0))
    emitter.importance = 1.0
    Cylinder(VANE_R, 1 * MM, parent=world, transform=translate(0, 0, -1 * MM), material=emitter)
    return world


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--angle-deg", type=float, required=True)
    parser.add_argument("--seconds", type=float, default=20.0, help="approximate trace time budget")
    parser.add_argument("--pixels", type=int, default=16)
    args = parser.parse_args()
    a = math.radians(args.angle_deg)
    t_build, c_build = time.perf_counter(), time.process_time()
    world = build_world()
    d = Vector3D(math.sin(a), 0.0, -math.cos(a))
    # camera plane passes through z = 310 mm on the beam line through the entrance centre
    s = 10 * MM / math.cos(a)
    origin = Point3D(-s * d.x, 0.0, LENGTH - s * d.z)
    width = 2 * R_OUT + 1 * MM
    pipeline = RadiancePipeline2D(display_progress=False, accumulate=True)
    camera = OrthographicCamera(
        (args.pixels, args.pixels), width, parent=world,
        transform=translate(origin.x, origin.y, origin.z) * rotate_basis(d, Vector3D(0, 1, 0)),
        pipelines=[pipeline],
    )
    camera.quiet = True
    camera.render_engine = SerialEngine()
    camera.spectral_bins = 1
    camera.min_wavelength, camera.max_wavelength = 500.0, 501.0  # L = 1 W/m^2/sr/nm x 1 nm
    camera.ray_max_depth = 21
    camera.ray_importance_sampling = True
    camera.pixel_samples = 50
    # the timing includes the first pass, which builds the accelerator and importance tables
    t0 = t_build
    c0 = c_build
    passes = 0
    while True:
        camera.observe()
        passes += 1
        if time.perf_counter() - t0 > args.seconds:
            break
    seconds = time.perf_counter() - t0
    cpu_seconds = time.process_time() - c0
    frame = pipeline.frame
    a_pix = (width / args.pixels) ** 2
    denom = math.pi * R_IN**2 * math.cos(a)
    ratio = float(np.sum(frame.mean) * a_pix / denom)
    stderr = float(math.sqrt(np.sum(frame.errors() ** 2)) * a_pix / denom)
    rays = int(np.sum(frame.samples))
    print(json.dumps({"tracer": "raysect", "version": "0.9.1", "angle_deg": args.angle_deg,
                      "ratio": ratio, "stderr": stderr, "rays": rays, "seconds": seconds, "cpu_seconds": cpu_seconds}))


if __name__ == "__main__":
    main()
