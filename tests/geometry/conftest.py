import pytest


@pytest.fixture(scope="session")
def reference():
    """The BENCHMARK.md tube, tessellated at 0.05 mm (cached by geometry.scenes)."""
    from geometry.scenes import reference_scene

    return reference_scene(tolerance_mm=0.05)
