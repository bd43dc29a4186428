"""The closed-detector test of straylight.detectors without trimesh equals trimesh's own answer
(``Trimesh(process=True).is_watertight``: vertices merged at 1e-8, every edge in exactly two triangles)."""
import numpy as np
import pytest
import trimesh

from straylight.detectors import is_watertight_merged


def _cases():
    box = trimesh.creation.box(extents=(3.0, 2.0, 0.5))
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=12.5)
    disk = trimesh.creation.annulus(r_min=0.0 + 1e-3, r_max=4.0, height=0.5)
    v, f = np.asarray(box.vertices), np.asarray(box.faces)
    out = [(np.asarray(m.vertices), np.asarray(m.faces)) for m in (box, sphere, disk)]
    out.append((v, f[1:]))  # one triangle missing: open
    for shift in (3e-10, 3e-7):  # a corner split in two: closed again by the 1e-8 merge, or not
        f2 = f.copy()
        f2[0, 0] = len(v)
        out.append((np.concatenate([v, v[f[0, 0]][None] + shift]), f2))
    top = f[np.asarray(box.face_normals)[:, 2] > 0.5]
    out.append((v, top))  # an open sheet (a detector disk of a tessellated scene)
    return out


@pytest.mark.parametrize("case", range(7))
def test_is_watertight_merged_equals_trimesh(case):
    v, f = _cases()[case]
    assert is_watertight_merged(v, f) == bool(trimesh.Trimesh(v, f, process=True).is_watertight)


def test_the_cases_cover_both_answers():
    answers = {bool(trimesh.Trimesh(v, f, process=True).is_watertight) for v, f in _cases()}
    assert answers == {True, False}
