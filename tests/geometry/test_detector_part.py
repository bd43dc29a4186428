import pytest


def test_rectangular_detector_width_is_along_x_and_height_along_y():
    """The docstring's promise: width_mm spans x, height_mm spans y (cq.Face.makePlane swaps them)."""
    from geometry.parts.detector import rectangular_detector

    bb = rectangular_detector(10.0, 2.0).shape.BoundingBox()
    assert (bb.xmin, bb.xmax) == pytest.approx((-5.0, 5.0))
    assert (bb.ymin, bb.ymax) == pytest.approx((-1.0, 1.0))
