"""Parametric CadQuery parts tessellated to tagged triangle meshes."""
from geometry.mesh import GeometryError, Part, Scene  # noqa: F401
