import os

os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")
# CAD tessellations are cached on disk (geometry.cad_cache); tests start cold unless they test the cache.
os.environ.setdefault("STRAYLIGHT_CACHE", "off")


import shutil  # noqa: E402
import stat  # noqa: E402
from pathlib import Path  # noqa: E402

import pytest  # noqa: E402

NOBODY_UID = 65534
CHECKOUT = Path(__file__).resolve().parent.parent


def _closed_to_others(path: Path) -> Path | None:
    """The first folder from ``path`` up that other users cannot enter (None: all can)."""
    for folder in (path, *path.parents):
        if not folder.stat().st_mode & stat.S_IXOTH:
            return folder
    return None


@pytest.fixture
def as_nobody():
    """``as_nobody(cmd, why)``: ``cmd`` run as the unprivileged user ``nobody`` (the tests run as root,
    to whom nothing is read-only); skips, saying ``why`` the test needs it, where setpriv is missing or
    the checkout sits in a folder other users cannot enter (``mktemp -d`` makes mode 0700 folders)."""
    def wrap(cmd, why: str):
        setpriv = shutil.which("setpriv")
        if setpriv is None:
            pytest.skip(f"running as root without setpriv: {why}")
        closed = _closed_to_others(CHECKOUT)
        if closed is not None:
            pytest.skip(f"{closed} is closed to other users (mode {stat.S_IMODE(closed.stat().st_mode):o}), "
                        f"so nobody cannot import the checkout: {why}")
        return [setpriv, f"--reuid={NOBODY_UID}", f"--regid={NOBODY_UID}", "--clear-groups", *cmd]
    return wrap


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
