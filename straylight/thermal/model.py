"""A scene prepared for thermal tracing: triangles, parts, roles, temperatures, the materials of
each side at each traced wavelength, and Kirchhoff emissivity tables (CONTRACTS §7).

Conventions (docs/thermal.md):

- A part emits from the front of each triangle (the side its normal points to: outward for a
  closed solid; for an analytic surface the side of ``axis``). Hit from the front, a triangle
  shows its part's ``material``; from the back, ``back_material`` when the part has one, else the
  same material (the engine's two-sided convention).
- epsilon(lambda, theta) = 1 - rho - T of the material on that side (materials.wavelength);
  ``absorber`` and ``detector`` parts 1; ``mirror`` parts 1 - the mirror reflectance.
- Emissivity depends on the polar angle only (isotropic materials): a table on ``THETA_GRID``.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np

from materials.flags import ComponentFlags, flags_of
from materials.wavelength import (
    at_wavelength,
    emissivity,
    hemispherical_emissivity,
    wavelength_dependent,
)
from straylight.intersect.exact_boundary import ExactBoundaryIntersector, plane_parts, rim_parts

THETA_GRID = np.linspace(0.0, np.pi / 2, 181)  # 0.5 deg: the tables are interpolated linearly in theta
MAX_SUB_BANDS = 16
SUB_BAND_RATIO = 1.1  # largest hi/lo of one traced sub-band when a material depends on wavelength


def sub_bands(lo_um: float, hi_um: float, dependent: bool) -> list[tuple[float, float, float]]:
    """[(lo, hi, traced wavelength um)]: the band itself when no material depends on wavelength,
    else sub-bands equal in log(lambda) with hi/lo <= 1.1 (at most 16), each traced at its
    geometric centre (the band integral then errs at second order in the material's change
    across a sub-band)."""
    if not dependent:
        return [(lo_um, hi_um, float(np.sqrt(lo_um * hi_um)))]
    k = int(min(MAX_SUB_BANDS, max(2, np.ceil(np.log(hi_um / lo_um) / np.log(SUB_BAND_RATIO)))))
    edges = np.geomspace(lo_um, hi_um, k + 1)
    return [(float(a), float(b), float(np.sqrt(a * b))) for a, b in itertools.pairwise(edges)]


def split_rays(n: int, share, min_rays: int) -> np.ndarray:
    """``n`` rays shared in proportion to ``share`` (largest remainders, so they add up to ``n``
    exactly), each sub-band with a share getting at least ``min_rays`` when ``n`` allows."""
    share = np.asarray(share, float)
    on = share > 0
    if not on.any():
        return np.zeros(len(share), np.int64)
    n = max(int(n), int(min_rays) * int(on.sum())) if min_rays > 2 else max(int(n), 2 * int(on.sum()))
    floor_n = min(int(min_rays), n // int(on.sum()))
    exact = share / share.sum() * (n - floor_n * on.sum())
    counts = np.floor(exact).astype(np.int64)
    rest = n - floor_n * int(on.sum()) - int(counts.sum())
    order = np.argsort(-(exact - counts), kind="stable")
    counts[order[:rest]] += 1
    return np.where(on, counts + floor_n, 0)


@dataclass(eq=False)
class ThermalScene:
    """Arrays of one scene for the thermal walks (built by :func:`thermal_scene`)."""

    scene: Any
    part_names: tuple
    roles: tuple  # per part: "surface" | "mirror" | "absorber" | "detector"
    temperature_k: np.ndarray  # (P,) 0 = does not emit
    materials: dict  # resolved material name -> model
    triangles_mm: np.ndarray  # (T, 3, 3)
    triangle_part: np.ndarray  # (T,)
    normals: np.ndarray  # (T, 3) unit, the front side
    plane_d: np.ndarray  # (T,) n . v0
    areas_mm2: np.ndarray  # (T,)
    eps_mm: float
    mirror_reflectance: float = 1.0
    planes: dict = field(default_factory=dict)  # part -> geometry.analytic.Plane: exact disks and annuli
    one_sided: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))  # (P,) analytic or open-sheet parts
    _isect: object = field(default=None, repr=False)
    _sides: dict = field(default_factory=dict, repr=False)

    @property
    def n_parts(self) -> int:
        return len(self.part_names)

    @property
    def intersector(self):
        if self._isect is None:
            from straylight.intersect.embree import EmbreeIntersector

            isect = EmbreeIntersector(self.triangles_mm)
            # hits on analytic planes, and on curved parts' rims, count inside their exact boundary only
            # (as in the engine)
            rims = rim_parts(tuple(getattr(p, "surface", None) for p in self.scene.parts), self.triangles_mm,
                             self.triangle_part)
            self._isect = ExactBoundaryIntersector(isect, self.triangle_part, self.planes, self.eps_mm, rims) \
                if self.planes or rims else isect
        return self._isect

    def is_role(self, *roles) -> np.ndarray:
        """(P,) bool: the parts whose role is one of ``roles``."""
        return np.array([r in roles for r in self.roles], dtype=bool)

    def part_index(self, name: str) -> int:
        return self.part_names.index(self.scene.resolve(name) if name not in self.part_names else name)

    def part_area_mm2(self, p: int) -> float:
        """An analytic plane's exact area; a curved analytic surface meshed by the project (its mesh covers
        the clear aperture) the surface's area over the aperture (``clear_area_mm2``); otherwise the
        triangles' area."""
        if p in self.planes:
            return float(self.planes[p].area_mm2)
        part = self.scene.parts[p]
        meta = getattr(part, "meta", None) or {}
        clear_area = getattr(getattr(part, "surface", None), "clear_area_mm2", None)
        own_mesh = meta.get("kind") == "sheet" and "tolerance_mm" in meta  # analytic_part's covering mesh
        area = clear_area() if own_mesh and clear_area is not None else None
        return float(area) if area is not None else float(self.areas_mm2[self.triangle_part == p].sum())

    def side_materials(self, p: int) -> tuple:
        """(front, back) material models of part ``p`` (None for non-surface roles)."""
        part = self.scene.parts[p]
        if part.role != "surface":
            return None, None
        front = self.materials[part.material]
        back = self.materials[part.back_material] if getattr(part, "back_material", None) else front
        return front, back

    def wavelength_dependent(self) -> bool:
        return any(wavelength_dependent(m) for m in self.materials.values())

    def sides_at(self, wavelength_um: float) -> SideTables:
        """Materials and emissivity tables of every part's two sides at ``wavelength_um`` (cached)."""
        key = round(float(wavelength_um), 12)
        if key not in self._sides:
            self._sides[key] = _side_tables(self, float(wavelength_um))
        return self._sides[key]


@dataclass(eq=False)
class SideTables:
    """Per part and side (0 front, 1 back): the material at one wavelength and 1 - rho - T on
    THETA_GRID (for absorbers and detectors 1; mirrors 1 - R)."""

    wavelength_um: float
    material: list  # [P][2] model or None
    eps: np.ndarray  # (P, 2, G)

    @cached_property
    def material_index(self) -> np.ndarray:
        """(P, 2) index of each side's material in :attr:`models` (-1: none), to group hits by material."""
        ids: dict = {}
        out = np.full((len(self.material), 2), -1, dtype=np.int64)
        for p, pair in enumerate(self.material):
            for s, m in enumerate(pair):
                if m is not None:
                    out[p, s] = ids.setdefault(id(m), len(ids))
        return out

    @cached_property
    def models(self) -> list:
        found: dict = {}
        for pair in self.material:
            for m in pair:
                if m is not None:
                    found.setdefault(id(m), m)
        return list(found.values())

    def emissivity(self, part, side, theta):
        """epsilon at (part, side, theta rad) arrays, linear in theta."""
        G = len(THETA_GRID)
        g = (G - 1) * np.clip(theta, 0.0, np.pi / 2) / (np.pi / 2)
        i = np.minimum(g.astype(np.int64), G - 2)
        f = g - i
        flat = self.eps.reshape(-1)
        base = (np.asarray(part) * 2 + np.asarray(side)) * G + i
        return flat[base] * (1 - f) + flat[base + 1] * f

    def hemispherical(self, p: int, side: int = 0) -> float:
        return hemispherical_emissivity(self.eps[p, side], THETA_GRID)


def _side_tables(ts: ThermalScene, wavelength_um: float) -> SideTables:
    lam_nm = wavelength_um * 1e3
    cache = {}
    mats, eps = [], np.zeros((ts.n_parts, 2, len(THETA_GRID)))
    for p, role in enumerate(ts.roles):
        if role in ("absorber", "detector"):
            mats.append([None, None])
            eps[p] = 1.0
            continue
        if role == "mirror":
            mats.append([None, None])
            eps[p] = 1.0 - ts.mirror_reflectance
            continue
        pair = []
        for s, m in enumerate(ts.side_materials(p)):
            if id(m) not in cache:
                mm = at_wavelength(m, lam_nm)
                cache[id(m)] = (mm, emissivity(mm, THETA_GRID), _back_emissivity(mm))
            mm, e_front, e_back = cache[id(m)]
            pair.append(mm)
            # the back side of a dielectric is its medium (Fresnel from inside)
            eps[p, s] = e_back if (s == 1 and e_back is not None) else e_front
        mats.append(pair)
    return SideTables(wavelength_um, mats, eps)


def _back_emissivity(material):
    """1 - rho - T seen from inside a transmitting (dielectric) medium, None for other materials."""
    if not flags_of(material) & ComponentFlags.DELTA_TRANSMISSION:  # only a dielectric has a medium behind it
        return None
    c = np.cos(THETA_GRID)
    coef = material.smooth_coefficients(c, back=True)
    rho = material.lobe_reflectance(THETA_GRID, "u") + coef.reflectance("u") + coef.transmittance("u")
    return np.clip(1.0 - rho, 0.0, 1.0)


def thermal_scene(scene, materials: dict, mirror_reflectance: float = 1.0) -> ThermalScene:
    """Arrays of ``scene`` (geometry.Scene) with resolved ``materials`` for the thermal walks: the
    scene's own triangles (an analytic plane part's mesh covers its exact disk: the intersector
    counts the hits inside it only, :attr:`ThermalScene.intersector`)."""
    from straylight.engine.spec import scene_epsilon  # the engine's offset rule (a heavy module: numba kernels)

    tri = np.asarray(scene.triangles_mm, dtype=np.float64)
    part = np.asarray(scene.triangle_part, dtype=np.int64)
    planes = plane_parts(tuple(getattr(p, "surface", None) for p in scene.parts))
    tri = _detectors_face_the_scene(scene, tri, part, planes)
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    twice = np.linalg.norm(cross, axis=1)
    normals = cross / np.where(twice > 0, twice, 1.0)[:, None]
    temps = np.array([float(p.meta.get("temperature_k", 0.0)) for p in scene.parts])
    return ThermalScene(scene=scene, part_names=tuple(p.name for p in scene.parts),
                        roles=tuple(p.role for p in scene.parts), temperature_k=temps, materials=dict(materials),
                        triangles_mm=tri, triangle_part=part, normals=normals,
                        plane_d=np.einsum("ij,ij->i", normals, tri[:, 0]), areas_mm2=0.5 * twice,
                        eps_mm=scene_epsilon(tri), mirror_reflectance=float(mirror_reflectance), planes=planes,
                        one_sided=np.array([_one_sided(p) for p in scene.parts], dtype=bool))


def _one_sided(part) -> bool:
    """A part whose back can be seen: an analytic surface or an open mesh (a closed solid's back is
    inside it). In the detector-power walks its back absorbs *and* emits, with the back's material
    (Kirchhoff; without it an isothermal enclosure holding a thin detector would read below pi B)."""
    if getattr(part, "surface", None) is not None:
        return True
    return not bool(part.meta.get("watertight", part.is_watertight))


def _detectors_face_the_scene(scene, tri, part, planes):
    """An open (sheet) detector mesh whose area-weighted normal points away from the centre of the
    other parts' bounding box is turned round (vertex order reversed), so that its front, the side
    that receives and emits, faces the instrument: an STL's winding is often arbitrary. Analytic
    detectors keep their ``axis`` (CONTRACTS §6.1) and closed ones their outward faces."""
    out = tri
    for p, prt in enumerate(scene.parts):
        if prt.role != "detector" or p in planes or prt.meta.get("watertight", prt.is_watertight):
            continue
        mine = part == p
        others = tri[~mine]
        if len(others) == 0:
            continue
        centre = 0.5 * (others.reshape(-1, 3).min(axis=0) + others.reshape(-1, 3).max(axis=0))
        t = tri[mine]
        cross = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])  # area-weighted normals
        if float(np.einsum("ij,ij->", cross, centre - t.mean(axis=1))) < 0:
            out = out.copy() if out is tri else out
            out[mine] = t[:, ::-1]
    return out


def temperatures_with(ts: ThermalScene, settings) -> np.ndarray:
    """The scene's part temperatures with ``settings`` applied in order: ``"PATTERN=K"`` strings
    (or (pattern, K) pairs), PATTERN a part name or a shell pattern (``vane_*``, ``*``). A pattern
    that names no part, or a bad value, is a one-line error."""
    import fnmatch

    temps = np.array(ts.temperature_k, dtype=float)
    for item in settings or ():
        if isinstance(item, str):
            pattern, sep, value = item.rpartition("=")
            if not sep or not pattern:
                raise ValueError(f"--temperature-k: expected PART=KELVIN, got {item!r}")
        else:
            pattern, value = item
        try:
            k = float(value)
        except ValueError:
            raise ValueError(f"--temperature-k {item!r}: {value!r} is not a number") from None
        if not (0 <= k < float("inf")):
            raise ValueError(f"--temperature-k {item!r}: a temperature must be >= 0 K")
        from geometry.limits import temperature_limit_message

        if temperature_limit_message(k):
            raise ValueError(f"--temperature-k {item!r}: {temperature_limit_message(k)}")
        hit = [i for i, part in enumerate(ts.scene.parts)  # its own name or an alias (CONTRACTS 6.2)
               if any(fnmatch.fnmatchcase(n, pattern) for n in ts.scene.names_of(part))]
        if not hit:
            raise ValueError(f"--temperature-k {item!r}: no part named {pattern!r}; parts: {', '.join(ts.part_names)}")
        temps[hit] = k
    return temps
