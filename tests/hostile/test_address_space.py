"""Hostile input: a scene too big for the address space left under ``ulimit -v`` aborted inside Embree
(SIGABRT / SIGSEGV, no message). It is now refused before Embree starts, in one line with the estimate."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from straylight.budget import EMBREE_BYTES_PER_TRIANGLE, check_embree_address_space

ROOT = Path(__file__).resolve().parents[2]


def test_estimate_against_the_room_left():
    check_embree_address_space(1000, left_bytes=1000 * EMBREE_BYTES_PER_TRIANGLE)
    with pytest.raises(ValueError, match=r"11,500,000 triangles need about 6.43 GB .* than the 1 GB left"):
        check_embree_address_space(11_500_000, left_bytes=2**30)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="RLIMIT_AS and /proc are Linux")
def test_big_mesh_under_ulimit_is_refused_not_aborted(tmp_path):
    code = """
import numpy as np, resource
from straylight.intersect.embree import EmbreeIntersector
soft, hard = resource.getrlimit(resource.RLIMIT_AS)
used = int(open('/proc/self/statm').read().split()[0]) * resource.getpagesize()
tri = np.random.default_rng(0).random((2_000_000, 3, 3))
resource.setrlimit(resource.RLIMIT_AS, (used + tri.nbytes + 400 * 2**20, hard))
try:
    EmbreeIntersector(tri)
except ValueError as exc:
    print("REFUSED", exc)
"""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    res = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120,
                         cwd=tmp_path)
    assert res.returncode == 0, (res.returncode, res.stderr[-500:])  # main: killed by SIGABRT/SIGSEGV or MemoryError
    assert "REFUSED the scene's 2,000,000 triangles need about" in res.stdout
