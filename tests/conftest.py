import os

os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")
# CAD tessellations are cached on disk (geometry.cad_cache); tests start cold unless they test the cache.
os.environ.setdefault("STRAYLIGHT_CACHE", "off")


import pytest  # noqa: E402


@pytest.fixture
def cad_bench_scene(tmp_path):
    """A scene file over tests/data/cad/ocp_bench_m.step (OCP's XDE writer, metre units): the solids
    as parts, the one named ``detector`` a detector, a slightly tilted collimated beam."""
    from pathlib import Path

    step = tmp_path / "bench.step"
    step.write_bytes((Path(__file__).resolve().parent / "data" / "cad" / "ocp_bench_m.step").read_bytes())
    toml = tmp_path / "scene.toml"
    toml.write_text(f"""
[[part]]
name = "cad"
mesh = "{step.name}"
split = "solids"
tolerance_mm = 0.1
material = "z302_sample_b"
[part.solids.detector]
role = "detector"

[[source]]
type = "collimated_disk"
center_mm = [3.0, 2.0, 150.0]
normal = [0.0, 0.0, -1.0]
direction = [0.05, 0.02, -0.9985]
radius_mm = 40.0
power_w = 1.0
""")
    return toml
