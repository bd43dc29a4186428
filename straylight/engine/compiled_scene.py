"""Stage 2, the scene as the kernels see it: triangle planes, detector samplers and the embree
scene, built once per process and scene (kept by :meth:`straylight.engine.runtime.Runtime.scene`),
with per-thread scratch buffers.

Detector sampling tables come from :class:`straylight.detectors.DetectorGeometry` through its
public ``alias_table`` and ``vertex_and_edges_mm``; :func:`detector_samplers` builds them without
any intersector (the result builder needs only them)."""
from __future__ import annotations

import threading
from typing import NamedTuple

import numpy as np

from straylight.detectors import DetectorGeometry
from straylight.engine.spec import TraceSpec
from straylight.intersect._plane import triangle_planes
from straylight.intersect.embree import EmbreeIntersector
from straylight.intersect.exact_boundary import ExactBoundaryIntersector, plane_parts, rim_parts
from straylight.intersect.reference import ReferenceIntersector


class SceneArrays(NamedTuple):
    """What the compiled kernels read of the scene (one argument)."""

    triangle_part: np.ndarray  # (T,) int32
    part_roles: np.ndarray  # (P,) int64, straylight.engine.spec.ROLE_*
    normals: np.ndarray  # (T, 3) unit geometric normals
    plane_d: np.ndarray  # (T,) n . v0 of each triangle's plane
    centroids: np.ndarray  # (T, 3)
    detector_of_part: np.ndarray  # (P,) detector index, -1 for other parts
    detector_area_mm2: np.ndarray  # (D,)
    # every detector's sampling table, concatenated: rows det_offset[j]:det_offset[j+1] are detector j's
    det_offset: np.ndarray
    det_alias_prob: np.ndarray
    det_alias: np.ndarray
    det_v0: np.ndarray
    det_e1: np.ndarray
    det_e2: np.ndarray
    det_normals: np.ndarray
    # analytic plane detectors (CONTRACTS §6.4), per detector: [inner^2, outer^2] (outer^2 = 0: sample the
    # triangles), and the disk's centre, in-plane axes and normal
    det_disk_r2: np.ndarray
    det_disk_centre: np.ndarray
    det_disk_u: np.ndarray
    det_disk_v: np.ndarray
    det_disk_normal: np.ndarray


def detector_samplers(spec: TraceSpec) -> list:
    """One :class:`DetectorGeometry` per detector part, in part order."""
    tri = spec.triangles_mm
    planes = plane_parts(spec.part_surfaces)
    return [DetectorGeometry.from_plane(tri[spec.triangle_part == p], planes[p]) if p in planes
            else DetectorGeometry.from_triangles(tri[spec.triangle_part == p]) for p in spec.detector_parts]


def _disk_rows(dets, field, width):
    """(D, width) array of one :class:`~straylight.detectors.Disk` field per detector (zeros where none)."""
    out = np.zeros((len(dets), width))
    for j, g in enumerate(dets):
        if g.disk is not None:
            out[j] = [g.disk.r2_in, g.disk.r2_out] if field == "r2" else getattr(g.disk, field)
    return np.ascontiguousarray(out)


class TargetSampler:
    """Area sampling of the (flat) target parts and the density of a direction toward them
    (straylight.engine.targets); its own intersector over the target triangles."""

    def __init__(self, spec: TraceSpec, reference: bool):
        idx = [spec.part_names.index(name) for name in spec.options.estimator.target_parts]
        ttri = spec.triangles_mm[np.isin(spec.triangle_part, idx)]
        self.geometry = DetectorGeometry.from_triangles(ttri)
        self.isect = ReferenceIntersector(ttri) if reference else EmbreeIntersector(ttri)
        self.plane_d = np.einsum("ij,ij->i", self.geometry.normals, ttri[:, 0])


class CompiledScene:
    """Per process: intersector, triangle planes, detector samplers and tables, target sampler."""

    def __init__(self, spec: TraceSpec, intersector=None):
        self.isect = intersector if intersector is not None else EmbreeIntersector(spec.triangles_mm)
        planes = plane_parts(spec.part_surfaces)
        rims = rim_parts(spec.part_surfaces, spec.triangles_mm, spec.triangle_part)
        if planes or rims:  # hits on analytic planes, and on curved parts' rims, count inside their exact boundary
            self.isect = ExactBoundaryIntersector(self.isect, spec.triangle_part, planes, spec.eps, rims)
        tri = spec.triangles_mm
        planes = getattr(self.isect, "planes", None)  # our intersectors computed them from these triangles
        v0, self.normals, centroids = planes if planes is not None else triangle_planes(tri)
        plane_d = np.einsum("ij,ij->i", self.normals, v0)
        self.det_parts = spec.detector_parts
        det_of_part = np.full(len(spec.part_names), -1, dtype=np.int64)
        det_of_part[self.det_parts] = np.arange(len(self.det_parts))
        self.detectors = detector_samplers(spec)
        dets = self.detectors
        tables = [g.vertex_and_edges_mm for g in dets]

        def stacked(arrays, width, dtype):
            empty = np.zeros((0, width) if width else 0, dtype)
            return np.ascontiguousarray(np.concatenate([empty] + list(arrays)), dtype=dtype)

        self.arrays = SceneArrays(
            triangle_part=spec.triangle_part, part_roles=spec.part_roles, normals=self.normals, plane_d=plane_d,
            centroids=centroids, detector_of_part=det_of_part,
            detector_area_mm2=np.array([g.area_mm2 for g in dets], dtype=np.float64),
            det_offset=np.concatenate([[0], np.cumsum([len(g.normals) for g in dets])]).astype(np.int64),
            det_alias_prob=stacked((g.alias_table[0] for g in dets), 0, np.float64),
            det_alias=stacked((g.alias_table[1] for g in dets), 0, np.int64),
            det_v0=stacked((t[0] for t in tables), 3, np.float64),
            det_e1=stacked((t[1] for t in tables), 3, np.float64),
            det_e2=stacked((t[2] for t in tables), 3, np.float64),
            det_normals=stacked((g.normals for g in dets), 3, np.float64),
            det_disk_r2=_disk_rows(dets, "r2", 2), det_disk_centre=_disk_rows(dets, "centre_mm", 3),
            det_disk_u=_disk_rows(dets, "u_axis", 3), det_disk_v=_disk_rows(dets, "v_axis", 3),
            det_disk_normal=_disk_rows(dets, "normal", 3))
        targets = spec.options.estimator.target_parts
        self.target = TargetSampler(spec, reference=intersector is not None) if targets else None
        self._local = threading.local()  # per-thread scratch (dask may run several threads per process)

    def scratch(self, name, size):
        """A flat float64 scratch array of at least ``size`` elements, reused by this thread."""
        buf = getattr(self._local, name, None)
        if buf is None or buf.size < size:
            buf = np.empty(size)
            setattr(self._local, name, buf)
        return buf

    def thread_local(self, name, factory):
        """This thread's object ``name``, made by ``factory()`` on first use and kept (e.g. the tally
        log, reused between batches: fresh pages cost a page fault each the first time they are written)."""
        obj = getattr(self._local, name, None)
        if obj is None:
            obj = factory()
            setattr(self._local, name, obj)
        return obj
