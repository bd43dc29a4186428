"""Off-screen pictures: the 3-D view PNG is non-empty and shows the scene; detector maps plot."""
import numpy as np
import pytest

from geometry.mesh import Part, Scene
from materials import Lambertian
from straylight.analyses.types import Beam, Setup


@pytest.fixture(scope="module")
def box_setup():
    """A detector square under a grey plate, lit by a beam along -z through a gap."""
    def rect(name, z, half, role="surface"):
        v = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]], float)
        return Part(name, v, np.array([[0, 1, 2], [0, 2, 3]]), None if role == "detector" else "grey", role)

    wall = Part("wall", np.array([[-30, -30, 0], [-30, 30, 0], [-30, 30, 60], [-30, -30, 60]], float),
                np.array([[0, 1, 2], [0, 2, 3]]), "grey")
    scene = Scene((rect("detector", 0.0, 10.0, "detector"), rect("floor", -1.0, 30.0), wall))
    beam = Beam(center_mm=(0, 0, 80), axis=(0, 0, -1), radius_mm=20.0)
    return Setup(scene, {"grey": Lambertian(rd=0.5)}, beam, None, "detector")


def test_offscreen_png_is_nonempty_and_not_blank(box_setup, tmp_path):
    from PIL import Image

    from straylight import viz

    paths = viz.trace_ray_paths(box_setup, np.radians(30), n_rays=50, seed=1)
    assert len(paths) == 50 and all(len(p[0]) >= 2 for p in paths)
    out = viz.render_scene(box_setup.scene, tmp_path / "v.png", ray_paths=paths, window_size=(400, 300))
    assert out.stat().st_size > 5_000
    img = np.asarray(Image.open(out).convert("RGB"), dtype=float)
    assert img.shape[:2] == (300, 400)
    # a blank render is one flat colour; the scene and rays give many distinct pixels off white
    assert (img.std(axis=(0, 1)) > 10).all()
    assert (np.abs(img - 255).sum(axis=2) > 30).mean() > 0.02


def test_absorbed_colouring_needs_values(box_setup, tmp_path):
    from straylight import viz

    with pytest.raises(ValueError, match="absorbed_w"):
        viz.render_scene(box_setup.scene, tmp_path / "a.png", color_by="absorbed")
    from PIL import Image

    out = viz.render_scene(box_setup.scene, tmp_path / "a.png", color_by="absorbed",
                           absorbed_w={"floor": 0.3, "wall": 1e-3}, window_size=(300, 200))
    img = np.asarray(Image.open(out).convert("RGB"), dtype=float)
    assert (np.abs(img - 255).sum(axis=2) > 30).mean() > 0.02  # not blank


def test_detector_map_plot(box_setup, tmp_path):
    from straylight import viz
    from straylight.trace import trace

    res = trace(box_setup.scene, [box_setup.beam.source(0.0)], n_rays=5_000, seed=1, materials=box_setup.materials)
    assert res.detectors["detector"].power_w > 0
    viz.plot_detector_map(res.maps["detector"], tmp_path / "m.png")
    assert (tmp_path / "m.png").stat().st_size > 10_000
