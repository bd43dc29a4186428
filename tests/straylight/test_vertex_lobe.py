"""First-vertex sampling with the lobe's own draw (EstimatorOptions.vertex_lobe_sampling):
unbiased against an analog walk (no NEE, no vertex sampling: every path is a BRDF-sampled walk),
exact ledger, reproducible, and a real variance reduction on a narrow glossy lobe.

Scenes: a glossy plate (the z302_sample_b coating, whose K-correlation lobe is a few degrees
wide) lit by a tilted collimated beam, the detector a disk beside the specular direction (glossy);
the same plate seen through a flat fold mirror (specular: the strategy is left to the walk after
a mirror). Tolerances: 4 combined standard errors taken from the runs themselves.
"""
import math

import numpy as np
import pytest

from engine_helpers import disk_part
from geometry.mesh import Part, Scene
from straylight.sources import CollimatedDisk
from straylight.trace import EstimatorOptions, OutputOptions, TraceOptions, trace
from straylight.execution import Execution

ANALOG = TraceOptions(estimator=EstimatorOptions(nee=False))
FV = TraceOptions(estimator=EstimatorOptions(first_vertex_sampling=True))
LOBE = TraceOptions(estimator=EstimatorOptions(first_vertex_sampling=True, vertex_lobe_sampling=True))


@pytest.fixture(scope="module")
def glossy():
    from materials import load_material

    return {"glossy": load_material("z302_sample_b")}


def _tilted_disk(name, centre, normal, radius, role):
    """A disk part of ``radius`` at ``centre`` facing ``normal``."""
    d = disk_part(name, 0.0, radius, 256, role=role)
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(z, n)
    s, c = np.linalg.norm(v), float(z @ n)
    if s < 1e-12:
        rot = np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    else:
        k = v / s
        K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        rot = np.eye(3) + s * K + (1 - c) * K @ K
    return Part(name, d.vertices_mm @ rot.T + np.asarray(centre, float), d.faces, role=role)


def _plate_scene(offset_deg=6.0):
    """Plate z = 0 (r 30), beam at 40 deg incidence; detector (r 4) at 200 mm along a direction
    ``offset_deg`` off the specular one, facing the plate."""
    plate = disk_part("plate", 0.0, 30.0, 256, role="surface", material="glossy")
    a = math.radians(40.0 + offset_deg)
    c = 200.0 * np.array([math.sin(a), 0.0, math.cos(a)])
    det = _tilted_disk("det", c, -c, 4.0, "detector")
    return Scene((plate, det))


def _beam():
    a = math.radians(40.0)
    d = np.array([math.sin(a), 0.0, -math.cos(a)])
    return CollimatedDisk(center_mm=-100.0 * d, normal=d, direction=d, radius_mm=20.0)


def _agree(a, b, k=4.0):
    assert a.power_w > 0 and b.power_w > 0  # the geometry couples: no vacuous pass
    assert abs(a.power_w - b.power_w) <= k * math.hypot(a.stderr_w, b.stderr_w), (a, b)


def test_glossy_single_scatter_agrees_with_the_analog_walk(glossy):
    scene, src = _plate_scene(), _beam()
    # 4 sigma here is ~5 % of the answer; dropping the MIS weight of the lobe draw (counting its
    # share twice) fails it; dropping the uniform point's weight fails the next test (heavy tail)
    analog = trace(scene, src, 1_200_000, seed=11, materials=glossy, options=ANALOG)
    lobe = trace(scene, src, 120_000, seed=12, materials=glossy, options=LOBE)
    _agree(analog.detectors["det"], lobe.detectors["det"])
    assert abs(lobe.ledger["balance_residual_w"]) < 1e-9


def test_lobe_draw_cuts_the_error_of_first_vertex_sampling_on_a_glossy_lobe(glossy):
    """Same rays, same seed: the uniform detector point alone finds the lobe's peak rarely."""
    scene, src = _plate_scene(offset_deg=4.0), _beam()
    fv = trace(scene, src, 20_000, seed=5, materials=glossy, options=FV).detectors["det"]
    lobe = trace(scene, src, 20_000, seed=5, materials=glossy, options=LOBE).detectors["det"]
    _agree(fv, lobe)
    # measured 1.5 % against 11 % (seed 5), 1.3 % against 8.7 % (seed 6): ask for a third
    assert lobe.stderr_w / lobe.power_w < fv.stderr_w / fv.power_w / 3, (fv, lobe)


def test_specular_fold_then_glossy_plate_agrees_with_the_analog_walk(glossy):
    """Beam -> flat fold mirror (role mirror) -> glossy plate -> detector, plus the direct glossy
    paths: vertex sampling sees the plate lit only where the fold does not shadow it."""
    plate = disk_part("plate", 0.0, 30.0, 256, role="surface", material="glossy")
    fold = _tilted_disk("fold", [0.0, 0.0, 60.0], [0.3, 0.0, -1.0], 12.0, "mirror")
    det = _tilted_disk("det", [120.0, 0.0, 150.0], [-120.0, 0.0, -150.0], 6.0, "detector")
    scene = Scene((plate, fold, det))
    d = np.array([0.0, 0.0, -1.0])
    src = CollimatedDisk(center_mm=[0.0, 0.0, 120.0], normal=d, direction=d, radius_mm=25.0)
    analog = trace(scene, src, 200_000, seed=21, materials=glossy, options=ANALOG)
    lobe = trace(scene, src, 40_000, seed=22, materials=glossy, options=LOBE)
    _agree(analog.detectors["det"], lobe.detectors["det"])
    assert abs(lobe.ledger["balance_residual_w"]) < 1e-9


def test_same_numbers_for_any_batch_size_and_thread_count(glossy):
    from dataclasses import replace

    scene, src = _plate_scene(), _beam()
    ref = trace(scene, src, 5_432, seed=9, materials=glossy, options=replace(LOBE, batch_rays=1000))
    got = trace(scene, src, 5_432, seed=9, materials=glossy, options=replace(LOBE, batch_rays=3000), execution=Execution(threads=2))
    assert got.detectors["det"] == ref.detectors["det"]
    assert ref.detectors["det"].power_w > 0


SV = TraceOptions(estimator=EstimatorOptions(first_vertex_sampling=True, second_vertex_sampling=True))
SV_LOBE = TraceOptions(estimator=EstimatorOptions(first_vertex_sampling=True, second_vertex_sampling=True, vertex_lobe_sampling=True, second_vertex_lobe_sampling=True))


def _two_vertex_scene():
    """A beam from above lights a grey Lambertian floor A and a small glossy patch B beside it,
    tilted so that light from the floor leaves B along its specular direction into the detector
    (B's own single scatter goes elsewhere): double scatter A -> B -> detector through B's lobe,
    with B drawn far more often by the area strategy than by the walk from A."""
    a = disk_part("a", 0.0, 40.0, 128, role="surface", material="grey")
    b = _tilted_disk("b", [50.0, 0.0, 20.0], [-0.6, 0.0, 0.8], 6.0, "surface")
    b = Part("b", b.vertices_mm, b.faces, material="glossy", role="surface")
    det = _tilted_disk("det", [87.0, 0.0, 67.2], [-0.616, 0.0, -0.787], 6.0, "detector")
    d = np.array([0.0, 0.0, -1.0])
    return Scene((a, b, det)), CollimatedDisk(center_mm=[0.0, 0.0, 100.0], normal=d, direction=d, radius_mm=60.0)


def _via_b(res):
    """Power and stderr of the double-scatter paths source -> a -> b -> detector."""
    for g in res.paths.group(by=lambda ev, det: tuple(p for p, _ in ev)):
        if g.key == ("a", "b"):
            return g.power_w, g.stderr_w
    return 0.0, 0.0


def test_second_vertex_lobe_agrees_with_the_analog_walk_and_tames_the_double_scatter(glossy):
    """Without the lobe draw at B the walk's rare B -> detector hits carry the double scatter
    (75 % relative error on it at 4e4 rays, seed 32); with it 20 %. Dropping the walk's share
    after B (counting those hits twice) brings the 65 % back and fails the error check."""
    from dataclasses import replace

    from engine_helpers import StandInLambertian

    mats = {**glossy, "grey": StandInLambertian(0.5)}
    scene, src = _two_vertex_scene()
    analog = trace(scene, src, 400_000, seed=31, materials=mats, options=replace(ANALOG, output=OutputOptions(record_paths=True)))
    sv = trace(scene, src, 40_000, seed=32, materials=mats, options=replace(SV, output=OutputOptions(record_paths=True)))
    lobe = trace(scene, src, 40_000, seed=32, materials=mats, options=replace(SV_LOBE, output=OutputOptions(record_paths=True)))
    _agree(analog.detectors["det"], lobe.detectors["det"])
    assert abs(lobe.ledger["balance_residual_w"]) < 1e-9
    (pa, ea), (ps, es), (pl, el) = _via_b(analog), _via_b(sv), _via_b(lobe)
    assert pa > 0 and pl > 0
    assert abs(pl - pa) <= 4 * np.hypot(ea, el)
    assert el / pl < 0.5 * es / ps, ((ps, es), (pl, el))
