"""Tagged triangle meshes: the hand-off from geometry/ to straylight/.

A :class:`Part` is one named solid (or sheet) tessellated to triangles, in mm,
carrying a material *name* (geometry never imports materials) and a role.
A :class:`Scene` is an ordered tuple of parts; its flattened arrays give, for
every triangle, the index of the part it belongs to.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from geometry.limits import MAX_COORDINATE_MM, coordinate_limit_message

ROLES = ("surface", "mirror", "absorber", "detector")


MAX_PART_NAME_CHARS = 1024


class GeometryError(ValueError):
    """Bad geometry input; the message names the part or file."""


def check_part_name(name) -> str:
    """A part name (CONTRACTS 6): a non-empty string of printable characters, at most
    :data:`MAX_PART_NAME_CHARS` long; results, tables and view3d.html are keyed by it (
    an empty name or one holding NUL used to be accepted)."""
    if not isinstance(name, str) or not name.strip():
        raise GeometryError(f"part name must be a non-empty string, got {name!r}")
    if len(name) > MAX_PART_NAME_CHARS:
        raise GeometryError(f"part name {name[:40]!r}... is {len(name)} characters long; at most {MAX_PART_NAME_CHARS}")
    bad = [c for c in name if not c.isprintable()]
    if bad:
        raise GeometryError(f"part name {name!r} holds a control character ({bad[0]!r}); use printable characters")
    return name


@dataclass(frozen=True, eq=False)
class Part:
    """One named part.

    vertices_mm : (v, 3) float64
    faces : (m, 3) int64, counter-clockwise seen from outside (outward normals)
    material : material name (a preset, a file path or a scene [material.*] key), or None
    role : one of ROLES
    surface : optional analytic surface (geometry.analytic, CONTRACTS §6.1): the mesh finds the
        hits, the surface refines them and gives the exact normal; the front is its front side
    back_material : optional material name of the back side (default: ``material``)
    """

    name: str
    vertices_mm: np.ndarray
    faces: np.ndarray
    material: str | None = None
    role: str = "surface"
    meta: dict = field(default_factory=dict)
    surface: object = None
    back_material: str | None = None

    def __post_init__(self):
        check_part_name(self.name)
        if self.role not in ROLES:
            raise GeometryError(f"part {self.name!r}: unknown role {self.role!r}; expected one of {', '.join(ROLES)}")
        v = np.asarray(self.vertices_mm, dtype=np.float64)
        f = np.asarray(self.faces, dtype=np.int64)
        if v.ndim != 2 or v.shape[1] != 3:
            raise GeometryError(f"part {self.name!r}: vertices must be (n, 3), got {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
            raise GeometryError(f"part {self.name!r}: faces must be a non-empty (m, 3) array, got {f.shape}")
        if f.min() < 0 or f.max() >= len(v):
            raise GeometryError(f"part {self.name!r}: face index out of range")
        bad = ~np.isfinite(v).all(axis=1)
        if bad.any():  # a NaN vertex fails much later, as "Eigenvalues did not converge" in a plane fit
            raise GeometryError(f"part {self.name!r}: {int(bad.sum())} of {len(v)} vertices have a NaN or infinite "
                                f"coordinate (first: vertex {int(np.argmax(bad))})")
        far = np.abs(v).max()
        if far > MAX_COORDINATE_MM:
            raise GeometryError(f"part {self.name!r}: " + coordinate_limit_message(float(far), "a vertex coordinate"))
        object.__setattr__(self, "vertices_mm", v)
        object.__setattr__(self, "faces", f)

    @property
    def n_triangles(self) -> int:
        return len(self.faces)

    @property
    def is_watertight(self) -> bool:
        """Every edge shared by exactly two triangles (as ``trimesh``'s ``is_watertight``; numpy only, so
        loading a scene need not import trimesh)."""
        edges = np.sort(self.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        key = edges[:, 0] * (int(self.faces.max()) + 1) + edges[:, 1]
        _, counts = np.unique(key, return_counts=True)
        return bool(np.all(counts == 2))

    def to_trimesh(self):
        import trimesh

        return trimesh.Trimesh(self.vertices_mm, self.faces, process=False)


@dataclass(frozen=True, eq=False)
class Scene:
    """Ordered parts. Flattened triangle arrays are cached (the scene is immutable)."""

    parts: tuple[Part, ...]

    def __post_init__(self):
        object.__setattr__(self, "parts", tuple(self.parts))
        names = [p.name for p in self.parts]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise GeometryError(f"duplicate part name(s): {', '.join(dup)}")

    @property
    def part_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parts)

    def part(self, name: str) -> Part:
        """The part ``name`` names: its own name, or an alias of exactly one part (see :meth:`resolve`)."""
        name = self.resolve(name)
        for p in self.parts:
            if p.name == name:
                return p
        raise AssertionError(name)  # resolve() returned a part name

    def names_of(self, part: Part) -> tuple[str, ...]:
        """Every name ``part`` answers to: its own, then its aliases (a CAD solid's instance name, CONTRACTS 6.2)."""
        return (part.name, *(str(a) for a in part.meta.get("part_aliases", ())))

    def resolve(self, name: str) -> str:
        """The part name that ``name`` means: a part's own name, else an alias that only one part has (the
        instance name ``scope/lens:1`` of the part ``scope/lens``). Unknown or ambiguous: a GeometryError
        listing the names."""
        if name in self.part_names:
            return name
        hits = [p.name for p in self.parts if name in self.names_of(p)[1:]]
        if len(hits) == 1:
            return hits[0]
        if hits:
            raise GeometryError(f"{name!r} names {len(hits)} parts ({', '.join(hits)}); use one of these names")
        listed = ", ".join(p.name + (f" ({', '.join(self.names_of(p)[1:])})" if self.names_of(p)[1:] else "")
                           for p in self.parts)
        raise GeometryError(f"no part named {name!r}; parts (other names in brackets): {listed}")

    @cached_property
    def triangles_mm(self) -> np.ndarray:
        """(m, 3, 3) float64: all triangles, parts in order."""
        return np.concatenate([p.vertices_mm[p.faces] for p in self.parts], axis=0)

    @cached_property
    def triangle_part(self) -> np.ndarray:
        """(m,) int32: index into ``parts`` of each triangle."""
        return np.concatenate(
            [np.full(p.n_triangles, i, dtype=np.int32) for i, p in enumerate(self.parts)]
        )

    @cached_property
    def triangle_normals(self) -> np.ndarray:
        t = self.triangles_mm
        n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        length = np.linalg.norm(n, axis=1, keepdims=True)
        return n / np.where(length > 0, length, 1.0)

    @cached_property
    def bounds_mm(self) -> np.ndarray:
        t = self.triangles_mm.reshape(-1, 3)
        # column by column: the same numbers as t.min(axis=0), ~4x faster on (n, 3) arrays
        return np.array([[t[:, k].min() for k in range(3)], [t[:, k].max() for k in range(3)]])
