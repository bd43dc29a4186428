"""Stage 1, what a worker needs: :class:`TraceSpec` (picklable: triangles, part roles, resolved
materials, sources, options) built and checked once by :func:`make_spec`."""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field, replace

import numpy as np

from materials import load_material
from materials.wavelength import coatings_at
from straylight.budget import check_ray_budget
from straylight.detectors import DetectorGeometry
from straylight.engine.options import TraceError, TraceOptions
from straylight.engine.roles import ROLE_CODES, ROLE_DETECTOR
from straylight.engine.tally_rows import tally_rows
from straylight.rng import check_seed
from straylight.run_checks import check_origin_precision, check_part_precision
from straylight.sources import orthonormal_basis



def scene_epsilon(triangles_mm) -> float:
    """Scale-aware offset: max(1e-7 x bounding diagonal, 32 float32 ulps of the largest coordinate)."""
    pts = np.asarray(triangles_mm).reshape(-1, 3)
    lo = np.array([pts[:, k].min() for k in range(3)])  # column by column: as pts.min(axis=0), ~4x faster
    hi = np.array([pts[:, k].max() for k in range(3)])
    diag = float(np.linalg.norm(hi - lo))
    big = float(max(np.abs(lo).max(), np.abs(hi).max()))  # = max |coordinate|, without an |pts| copy
    return max(1e-7 * diag, 32.0 * float(np.spacing(np.float32(max(big, 1.0)))))


@dataclass(frozen=True, eq=False)
class TraceSpec:
    """Everything a worker needs to trace chunks; picklable (no embree objects)."""

    triangles_mm: np.ndarray
    triangle_part: np.ndarray
    part_names: tuple
    part_roles: np.ndarray
    part_material: np.ndarray  # index into ``materials`` per part, -1 where the part has none
    materials: tuple
    sources: tuple
    n_rays: int
    seed: int
    options: TraceOptions
    eps: float
    token: str = field(default="")  # content hash of the geometry: the key of the per-process scene cache
    vertex_table: object = None  # straylight.engine.first_vertex.VertexTable when first_vertex_sampling is on
    critical_table: object = None  # straylight.engine.second_vertex.CriticalTable when second_vertex_sampling is on
    entrance_table: object = None  # straylight.engine.entrance_sampling.EntranceTable when entrance_sampling is on
    eye_table: object = None  # straylight.engine.reverse_chain.EyeTable when reverse_chain is on (None: cosine eyes)
    direct_table: object = None  # straylight.engine.direct_area.DirectArea (or Declined) when direct_area is on
    lens_table: object = None  # straylight.engine.lens_vertex.LensTable when lens_vertex is on
    end_field: object = None  # straylight.engine.field_cone.FieldTable when delta_chain runs (the end draws' field)
    chunk_offset: int = 0  # local chunk k draws from the stream of chunk chunk_offset + k (Execution(first_chunk=))
    part_surfaces: tuple = ()  # analytic surface per part (geometry.analytic) or None
    part_back_material: np.ndarray = None  # index into ``materials`` of each part's back side, -1: as the front
    diffraction: object = None  # straylight.engine.diffraction.Diffraction when a part diffracts (CONTRACTS §6.5)
    #: the names of the strategies that run, as the plan decided (straylight.engine.plan; trace() sets it): the
    #: walk builds states for these only. None: the walk resolves the plan itself (make_spec, direct run_batch)
    strategies_on: tuple | None = None

    @property
    def detector_parts(self) -> np.ndarray:
        return np.flatnonzero(self.part_roles == ROLE_DETECTOR)

    @property
    def rows(self):
        """The :class:`~straylight.engine.tally_rows.TallyRows` of this scene."""
        return tally_rows(len(self.part_names), len(self.detector_parts))

    @property
    def n_rows(self) -> int:
        return self.rows.n_summed

    @property
    def total_power_w(self) -> float:
        return float(sum(s.power_w for s in self.sources))


def resolve_materials(scene, materials):
    """Material name -> model, for parts that scatter; returns (part_material (P,), models tuple).
    ``materials`` (e.g. a scene file's, already resolved) is used as given; a name it lacks is a
    preset or file name for ``materials.load_material``."""
    needed = _material_names(scene)
    models = []
    index = {}
    for name in needed:
        if name is None:
            bad = [p.name for p in scene.parts if p.role == "surface" and p.material is None]
            raise TraceError(f"surface part(s) {', '.join(bad)} have no material")
        if materials is not None and name in materials:
            model = materials[name]
        else:
            model = load_material(name)
        if any(getattr(c, "scatter", "brdf") == "btdf" for c in getattr(model, "components", ())):
            raise TraceError(f"material {name!r}: an imported BTDF table (scatter into transmission) is evaluated and "
                             "exported but not traced yet; use it with material eval/export (docs/bsdf-files.md)")
        index[name] = len(models)
        models.append(model)
    part_material = np.array([index.get(p.material, -1) if p.role == "surface" else -1 for p in scene.parts],
                             dtype=np.int64)
    return orient_materials(scene, part_material, models)


def _coatings_at_source_wavelength(models, sources):
    """The materials with their coatings at the sources' ``wavelength_nm`` (the traced wavelength, CONTRACTS
    5.1; materials.wavelength.coatings_at); as they are when no source states one. Sources of different
    wavelengths with a coated material in the scene are refused (one trace is one wavelength)."""
    waves = sorted({float(w) for w in (getattr(s, "wavelength_nm", None) for s in sources) if w is not None})
    if not waves:
        return models
    coated = [m for m in models if any(getattr(c, "coating", None) is not None for c in getattr(m, "components", ()))]
    if len(waves) > 1:
        if coated:
            raise TraceError(f"sources at {', '.join(f'{w:g}' for w in waves)} nm and a coated material "
                             f"({coated[0].name}): a trace is one wavelength; trace each source on its own")
        return models
    out = [coatings_at(m, waves[0]) for m in models]
    return type(models)(out) if isinstance(models, tuple) else out


def _anisotropic(model) -> bool:
    return any(getattr(c, "anisotropic", False) or getattr(c, "symmetry", "plane") == "none"
               for c in getattr(model, "components", ()))


def orient_materials(scene, part_material, models):
    """Anisotropic materials (an imported table with sample rotations, materials.bsdf_table) get one
    copy per surface part, told where the part's sample x axis lies in the tracer's local frame.

    The sample x axis is the part's own +x (its ``rotate_deg`` applied; docs/bsdf-files.md),
    projected on the part's plane (area-weighted mean of its outward triangle normals; its +y when
    +x is along the normal). The tracer's local frame at a hit is the Duff et al. basis of the
    facing normal (straylight.engine.interactions.brdf_scatter.frames), constant over a flat part, so
    the offset is exact there; a curved part uses its mean normal, and the back side of a part
    sees the front's orientation (an anisotropic sample is measured on one side).
    """
    models = list(models)
    if not any(_anisotropic(m) for m in models):
        return part_material, tuple(models)
    part_material = part_material.copy()
    for k, p in enumerate(scene.parts):
        idx = int(part_material[k])
        if idx < 0 or not _anisotropic(models[idx]):
            continue
        tri = p.vertices_mm[p.faces]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]).sum(axis=0)
        if not np.linalg.norm(n) > 0:
            continue
        n = n / np.linalg.norm(n)
        rot = np.asarray(p.meta.get("placement", {}).get("rotation", np.eye(3)), float)
        x = rot[:, 0] - np.dot(rot[:, 0], n) * n
        if np.linalg.norm(x) < 1e-6:
            x = rot[:, 1] - np.dot(rot[:, 1], n) * n
        t, b = orthonormal_basis(n)
        offset_deg = float(np.degrees(np.arctan2(np.dot(x, b), np.dot(x, t))))
        base = models[idx]
        comps = tuple(c.oriented(offset_deg) if hasattr(c, "oriented") else c for c in base.components)
        part_material[k] = len(models)
        models.append(replace(base, components=comps))
    return part_material, tuple(models)


def _material_names(scene) -> list:
    """Material names of the surface parts (front, and the back of analytic parts), sorted."""
    return sorted({p.material for p in scene.parts if p.role == "surface"}
                  | {p.back_material for p in scene.parts if p.role == "surface" and getattr(p, "back_material", None)},
                  key=str)


def back_material_index(scene) -> np.ndarray:
    """Index into the resolved models of each surface part's ``back_material`` (-1: none)."""
    index = {name: k for k, name in enumerate(_material_names(scene))}
    return np.array([index[p.back_material] if p.role == "surface" and getattr(p, "back_material", None) else -1
                     for p in scene.parts], dtype=np.int64)


AUTO_BATCH_RAYS = 60_000  # rays per in-memory batch unless set (batch_rays): enough to amortise the
# per-call overheads (50k ran ~10 % faster than 20k on the reference tube) and to trace the precision
# stop's minimum sample with its confirming look (6e4 rays, straylight.analyses.precision) in one batch
# (the guide scope's 20 and 30 deg points a few hundredths of a CPU s faster than 5e4); the per-ray state and the
# tally log (straylight.engine.tally_store: ~4 writes per ray on the 0.36M assembly) grow with the
# rays, not with the parts. Never changes results.


def _check_targets(scene, options):
    for name in options.estimator.target_parts:
        if name not in scene.part_names:
            raise TraceError(f"target part {name!r} not in the scene; parts: {', '.join(scene.part_names)}")
    if options.estimator.target_parts:
        ttri = np.concatenate([scene.part(n).vertices_mm[scene.part(n).faces] for n in options.estimator.target_parts])
        geo = DetectorGeometry.from_triangles(ttri)
        off = np.abs((ttri.reshape(-1, 3) - geo.origin_mm) @ geo.normal).max()
        size = float(np.ptp(ttri.reshape(-1, 3), axis=0).max())
        if off > 1e-6 * max(size, 1.0):
            raise TraceError(f"target parts {', '.join(options.estimator.target_parts)} must be flat (coplanar): "
                             f"vertices lie up to {off:.3g} mm off their plane")


def make_spec(scene, sources, n_rays, seed=0, materials=None, options=None) -> TraceSpec:
    """Check inputs and build the picklable :class:`TraceSpec` used by ``run_batch``."""
    options = options or TraceOptions()
    seed = check_seed(seed)
    if isinstance(n_rays, bool) or not isinstance(n_rays, (int, np.integer)) or int(n_rays) < 1:
        raise TraceError(f"n_rays must be a positive integer, got {n_rays!r}")
    check_ray_budget(n_rays, sum(p.role == "detector" for p in scene.parts), what="n_rays")
    if not isinstance(sources, (list, tuple)):
        sources = (sources,)
    if not sources:
        raise TraceError("at least one source is needed")
    if sum(s.power_w for s in sources) <= 0:
        raise TraceError("total source power_w must be > 0")
    try:  # Embree's float32 rounds far-away ray origins: warn, or refuse where rays would be lost
        check_origin_precision(sources, scene.bounds_mm)
    except ValueError as exc:
        raise TraceError(str(exc)) from None
    part_material, models = resolve_materials(scene, materials)
    models = _coatings_at_source_wavelength(models, sources)
    _check_targets(scene, options)
    from straylight.engine.diffraction import scene_diffraction
    from straylight.engine.estimators import without_diffraction_blind

    diffraction = scene_diffraction(scene, sources, models, options)
    if diffraction is not None:  # the strategies that do not see diffracting edges are turned off
        options = without_diffraction_blind(options)
    if options.estimator.first_vertex_sampling:
        from straylight.engine.first_vertex import unsupported

        why = unsupported(tuple(sources))
        if why:
            raise TraceError(why)
    tri = np.ascontiguousarray(scene.triangles_mm, dtype=np.float64)
    tri_part = np.ascontiguousarray(scene.triangle_part, dtype=np.int32)
    eps_mm = scene_epsilon(tri)
    try:  # the offset grows with the scene's extent: refuse it where it is a fraction of a part
        check_part_precision(scene.parts, eps_mm)
    except ValueError as exc:
        raise TraceError(str(exc)) from None
    roles = np.array([ROLE_CODES[p.role] for p in scene.parts], dtype=np.int64)
    h = hashlib.sha1(memoryview(tri).cast("B"))  # the bytes of tri.tobytes(), without copying them
    h.update(tri_part.tobytes())
    h.update(roles.tobytes())  # detector geometry depends on the roles,
    h.update(repr(options.estimator.target_parts).encode())  # and the target sampler on the targets
    surfaces = tuple(getattr(p, "surface", None) for p in scene.parts)
    h.update(repr([None if s is None else s.to_dict() for s in surfaces]).encode())  # exact plane boundaries
    if diffraction is not None:
        diffraction = replace(diffraction, past_mm=4.0 * eps_mm)
    return TraceSpec(
        triangles_mm=tri, triangle_part=tri_part, part_names=scene.part_names, part_roles=roles,
        part_material=part_material, materials=models, sources=tuple(sources), n_rays=int(n_rays), seed=seed,
        options=options, eps=eps_mm, token=h.hexdigest(),
        part_surfaces=surfaces,
        part_back_material=back_material_index(scene), diffraction=diffraction,
    )
