"""Parametric CadQuery parts tessellated to tagged triangle meshes.

``import geometry`` stays light (no CadQuery); the builders load it on first use:
``geometry.reference_scene()``, ``geometry.tube_scene(**params)``, ``geometry.reflectometer_scene(...)``.
"""
import atomicio.numba_cache  # noqa: F401 - compiled kernels cache in the user's cache folder, not the install
from geometry.mesh import GeometryError, Part, Scene  # noqa: F401

_LAZY = {"reference_scene": "geometry.scenes", "tube_scene": "geometry.scenes",
         "reflectometer_scene": "geometry.scenes", "TubeParams": "geometry.parts.tube",
         "load_part": "geometry.io", "load_scene": "geometry.io", "save_scene": "geometry.io",
         "check_scene": "geometry.checks", "tessellate": "geometry.tessellate"}


def __getattr__(name):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'geometry' has no attribute {name!r}")
