"""Forward Monte Carlo trace: sources -> surfaces (BRDF / mirror / absorber) -> detectors.

Estimators (every one reports a standard error from per-ray contributions):

- A ray starts with weight ``w0 = total power / n_rays``. At a ``surface`` hit it is scattered
  by the material's importance sampling, ``w <- w f cos / pdf`` (materials/base.py); at a
  ``mirror`` it reflects specularly, ``w <- R w``; ``absorber`` and ``detector`` parts end it.
- Next-event estimation (NEE) toward detector parts: at every BRDF scatter vertex x, one shadow
  ray to a point y drawn uniformly over each detector's area A; if unoccluded it adds
  ``w f(wi, wo) cos_x cos_y A / |y - x|^2 * m_nee`` (area form of the rendering equation, pdf 1/A).
  A random-walk hit on a detector straight after a BRDF scatter counts ``w * m_brdf``; hits after
  the source or a specular reflection count fully. ``m_nee + m_brdf = 1`` are power-heuristic MIS
  weights (Veach 1997, eq. 9.13) of the two densities per steradian, ``d^2 / (A cos_y)`` and the
  material's ``pdf``: NEE wins for diffuse coatings, BRDF sampling for narrow specular lobes (NEE
  alone is unbiased there too, but heavy-tailed: its error bars would be wrong in practice).
- Russian roulette: a weight below ``rr_threshold * w0`` survives with probability
  ``w / (rr_threshold w0)`` and is raised to ``rr_threshold w0`` (unbiased).

Ledger (exact per ray, so ``emitted = detected + absorbed + escaped`` to round-off):
``absorbed[part] = absorbed_physical + roulette + nee_exchange + truncated`` where
``roulette`` = weight roulette removed (zero in expectation), ``nee_exchange`` = the MIS
share of walk hits left to NEE minus the NEE contributions made from that part (zero in expectation) and
``truncated`` = weight still in flight after ``max_events`` (a small bias, reported).

Materials are two-sided: the local frame's z is the geometric normal flipped to face the
incoming ray; light leaves on the incident side only. Self-intersection: new origins are
offset by ``eps`` along that normal (see :func:`scene_epsilon`), shadow rays stop ``eps``
short of their target.
"""
from __future__ import annotations

import hashlib
import threading
from dataclasses import dataclass, field

import numpy as np

from straylight.detectors import DetectorGeometry, IrradianceMap
from straylight.paths import KIND_DETECTOR, KIND_SCATTER, KIND_SPECULAR, PathRecords, mix_key, stderr_from_sums
from straylight.rng import CHUNK_RAYS, ChunkStreams, batches, check_seed, chunk_bounds, chunk_rng, n_chunks
from straylight.sources import orthonormal_basis

ROLE_CODES = {"surface": 0, "mirror": 1, "absorber": 2, "detector": 3}
_SURFACE, _MIRROR, _ABSORBER, _DETECTOR = 0, 1, 2, 3


class TraceError(ValueError):
    """A trace request that cannot run; the message names the parameter or part."""


@dataclass(frozen=True)
class TraceOptions:
    """Options of :func:`trace` (see docs/engine.md)."""

    nee: bool = True
    max_events: int = 1000
    rr_threshold: float = 1e-3
    batch_rays: int | None = None  # None: auto_batch_rays(rows of the tally matrix)
    record_paths: bool = False
    path_depth: int = 12
    map_bins: tuple = (64, 64)
    polarization: str = "u"
    detector_sides: str = "both"
    progress: bool = False
    mirror_reflectance: float = 1.0
    target_parts: tuple = ()
    nee_samples: int = 1
    target_fraction: float = 0.5
    first_vertex_sampling: bool = False

    def __post_init__(self):
        if int(self.max_events) < 1:
            raise TraceError(f"max_events must be >= 1, got {self.max_events}")
        if not (0.0 <= float(self.rr_threshold) < 1.0):
            raise TraceError(f"rr_threshold must be in [0, 1), got {self.rr_threshold}")
        if int(self.nee_samples) < 1:
            raise TraceError(f"nee_samples must be >= 1, got {self.nee_samples}")
        if self.batch_rays is not None and int(self.batch_rays) < 1:
            raise TraceError(f"batch_rays must be >= 1, got {self.batch_rays}")
        if self.detector_sides not in ("both", "front"):
            raise TraceError(f"detector_sides must be 'both' or 'front', got {self.detector_sides!r}")
        if len(tuple(self.map_bins)) != 2 or min(self.map_bins) < 1:
            raise TraceError(f"map_bins must be two positive integers, got {self.map_bins!r}")
        if not (0.0 < float(self.target_fraction) < 1.0):
            raise TraceError(f"target_fraction must be in (0, 1), got {self.target_fraction}")
        if isinstance(self.target_parts, str):
            object.__setattr__(self, "target_parts", (self.target_parts,))
        object.__setattr__(self, "target_parts", tuple(self.target_parts))
        if not (0.0 <= float(self.mirror_reflectance) <= 1.0):
            raise TraceError(f"mirror_reflectance must be in [0, 1], got {self.mirror_reflectance}")


@dataclass(frozen=True)
class Tally:
    """A Monte Carlo estimate of a power and its standard error (1 sigma), in W."""

    power_w: float
    stderr_w: float

    def to_dict(self) -> dict:
        return {"power_w": self.power_w, "stderr_w": self.stderr_w}


def scene_epsilon(triangles_mm) -> float:
    """Scale-aware offset: max(1e-7 x bounding diagonal, 32 float32 ulps of the largest coordinate)."""
    pts = np.asarray(triangles_mm).reshape(-1, 3)
    diag = float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))
    big = float(np.abs(pts).max())
    return max(1e-7 * diag, 32.0 * float(np.spacing(np.float32(max(big, 1.0)))))


@dataclass(frozen=True, eq=False)
class TraceSpec:
    """Everything a worker needs to trace chunks; picklable (no embree objects)."""

    triangles_mm: np.ndarray
    triangle_part: np.ndarray
    part_names: tuple
    part_roles: np.ndarray
    part_material: np.ndarray
    materials: tuple
    sources: tuple
    n_rays: int
    seed: int
    options: TraceOptions
    eps: float
    token: str = field(default="")
    vertex_table: object = None  # straylight.first_vertex.VertexTable when first_vertex_sampling is on

    @property
    def detector_parts(self) -> np.ndarray:
        return np.flatnonzero(self.part_roles == _DETECTOR)

    @property
    def n_rows(self) -> int:
        return _Layout(len(self.part_names), len(self.detector_parts)).n_ext


class _Layout:
    """Row indices of the per-ray tally matrix."""

    def __init__(self, n_parts, n_det):
        p, d = n_parts, n_det
        self.P, self.D = p, d
        self.INC, self.FIRST, self.ABS, self.RR, self.NEX, self.TRUNC = (k * p for k in range(6))
        self.DET_NEE, self.DET_DIRECT, self.DET_WALK = 6 * p, 6 * p + d, 6 * p + 2 * d
        self.ESC = 6 * p + 3 * d
        self.n = self.ESC + 1
        self.LEDGER_ABS = self.n  # derived rows: absorbed ledger (P), detector total (D)
        self.DET_TOTAL = self.n + p
        self.n_ext = self.n + p + d


# ------------------------------------------------------------------ per-process compiled scene

_COMPILED: dict = {}  # token -> _Compiled; one embree scene per process and scene (cache only)


class _Compiled:
    def __init__(self, spec: TraceSpec, intersector=None):
        from straylight.intersect.embree import EmbreeIntersector

        self.isect = intersector if intersector is not None else EmbreeIntersector(spec.triangles_mm)
        tri = spec.triangles_mm
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        length = np.linalg.norm(n, axis=1, keepdims=True)
        self.normals = n / np.where(length > 0, length, 1.0)
        self.plane_d = np.einsum("ij,ij->i", self.normals, tri[:, 0])
        self.centroids = tri.mean(axis=1)
        self.det_parts = spec.detector_parts
        self.det_of_part = np.full(len(spec.part_names), -1, dtype=np.int64)
        self.det_of_part[self.det_parts] = np.arange(len(self.det_parts))
        self.detectors = [
            DetectorGeometry.from_triangles(tri[spec.triangle_part == p]) for p in self.det_parts
        ]
        self._local = threading.local()  # per-thread scratch (dask may run several threads per process)
        self.det_area = np.array([g.area_mm2 for g in self.detectors], dtype=np.float64)
        # all detectors' sampling tables, concatenated (rows det_off[j]:det_off[j+1] belong to detector j)
        self.det_off = np.concatenate([[0], np.cumsum([len(g.normals) for g in self.detectors])]).astype(np.int64)
        dets = self.detectors
        self.det_prob = np.concatenate([np.zeros(0)] + [g._alias[0] for g in dets]).astype(np.float64)
        self.det_alias = np.concatenate([np.zeros(0, np.int64)] + [g._alias[1] for g in dets]).astype(np.int64)
        self.det_v0, self.det_e1, self.det_e2 = (
            np.ascontiguousarray(np.concatenate([np.zeros((0, 3))] + [g._edges[k] for g in dets]), dtype=np.float64)
            for k in range(3))
        self.det_normals = np.ascontiguousarray(np.concatenate([np.zeros((0, 3))] + [g.normals for g in dets]),
                                                dtype=np.float64)
        self.target = self.target_isect = None
        if spec.options.target_parts:
            idx = [spec.part_names.index(name) for name in spec.options.target_parts]
            ttri = tri[np.isin(spec.triangle_part, idx)]
            self.target = DetectorGeometry.from_triangles(ttri)
            if intersector is None or isinstance(intersector, _NoIsect):
                from straylight.intersect.embree import EmbreeIntersector as _Target
            else:
                from straylight.intersect.reference import ReferenceIntersector as _Target
            self.target_isect = _Target(ttri) if not isinstance(intersector, _NoIsect) else None
            self.target_plane_d = np.einsum("ij,ij->i", self.target.normals, ttri[:, 0])


    def scratch(self, name, size):
        """A flat float64 scratch array of at least ``size`` elements, reused by this thread."""
        buf = getattr(self._local, name, None)
        if buf is None or buf.size < size:
            buf = np.empty(size)
            setattr(self._local, name, buf)
        return buf

    def tally_buffer(self, rows, n):
        """A zeroed (rows, n) float64 array, reused between batches of this thread (fresh pages from
        np.zeros cost a page fault each time they are first written). The batch that used it last
        left it all zeros (``chunk_sums(..., clear=True)`` then :meth:`tally_cleared`) unless it
        stopped half-way; only then is it filled again."""
        buf = getattr(self._local, "buf", None)
        if buf is None or buf.size < rows * n:
            buf = self._local.buf = np.zeros(rows * n)
        elif not getattr(self._local, "buf_clean", False):
            buf.fill(0.0)
        self._local.buf_clean = False
        return buf[:rows * n].reshape(rows, n)

    def tally_cleared(self):
        """Record that this thread's tally buffer is all zeros again."""
        self._local.buf_clean = True


_MALLOC_TUNED = []


def _keep_freed_memory():
    """glibc only, once per process: serve blocks up to 32 MB from the heap and keep up to 256 MB of
    freed heap (mallopt M_MMAP_THRESHOLD, M_TRIM_THRESHOLD). The engine frees and reallocates
    MB-sized arrays every event; with glibc's defaults many came back as fresh pages (6k-50k page
    faults per 4e5-ray trace, up to 10 % of its CPU), now ~100. Elsewhere: nothing."""
    if _MALLOC_TUNED:
        return
    _MALLOC_TUNED.append(True)
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6")
        libc.mallopt(-3, 32 * 1024 * 1024)  # M_MMAP_THRESHOLD (its maximum on 64-bit)
        libc.mallopt(-1, 256 * 1024 * 1024)  # M_TRIM_THRESHOLD
    except (OSError, AttributeError):
        pass


_COMPILED_LOCK = threading.Lock()


def _compiled(spec: TraceSpec, intersector=None) -> _Compiled:
    _keep_freed_memory()
    if intersector is not None:
        return _Compiled(spec, intersector)
    comp = _COMPILED.get(spec.token)
    if comp is None:
        with _COMPILED_LOCK:  # threads of one worker may start their first batch together: build once
            comp = _COMPILED.get(spec.token)
            if comp is None:
                _COMPILED.clear()  # keep one scene per process
                comp = _COMPILED[spec.token] = _Compiled(spec)
    return comp


# ------------------------------------------------------------------ one batch of chunks


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


def _emit(source, u, eps):
    """Emit and lift origins eps off the source's plane toward where each ray goes, so that a source
    laid on a surface (e.g. a Lambertian disk on a detector, for a backward trace) does not hit it."""
    from straylight._kernels import lift_origins

    o, d = source.emit(u)
    normal = getattr(source, "normal", None)
    if normal is None:
        return o + eps * d, d
    o = np.array(o, dtype=np.float64, order="C")  # a copy: the source's array is left alone
    d = np.ascontiguousarray(d, dtype=np.float64)
    return lift_origins(o, d, np.ascontiguousarray(normal, dtype=np.float64), float(eps)), d


def run_batch_reference(spec: TraceSpec, first_chunk: int, stop_chunk: int, intersector=None) -> dict:
    """Vectorised-numpy twin of :func:`run_batch` (the slow reference the compiled path is tested
    against: same random streams, same arithmetic order, bit-identical results)."""
    if spec.vertex_table is not None:
        raise TraceError("the numpy reference engine does not implement first_vertex_sampling")
    comp = _compiled(spec, intersector)
    opt = spec.options
    lay = _Layout(len(spec.part_names), len(comp.det_parts))
    C = CHUNK_RAYS
    start = first_chunk * C
    stop = min(stop_chunk * C, spec.n_rays)
    n = stop - start
    nch = stop_chunk - first_chunk
    gens = [chunk_rng(spec.seed, k) for k in range(first_chunk, stop_chunk)]
    powers = np.array([s.power_w for s in spec.sources], dtype=np.float64)
    total_power = float(powers.sum())
    w0 = total_power / spec.n_rays
    thr = opt.rr_threshold * w0
    M = np.zeros((lay.n, n))  # per-ray tallies, one row per tally
    D = len(comp.det_parts)
    K = int(opt.path_depth)
    bins = tuple(int(b) for b in opt.map_bins)
    both_sides = opt.detector_sides == "both"
    map_rows, path_rows = [], []

    # emission: chunk k draws (rays in chunk, 5) uniforms first
    u = np.concatenate([gens[c].random((chunk_bounds(first_chunk + c, spec.n_rays)[1] - (first_chunk + c) * C, 5))
                        for c in range(nch)])
    o = np.empty((n, 3))
    d = np.empty((n, 3))
    if len(spec.sources) == 1:
        o, d = _emit(spec.sources[0], u[:, 1:5], spec.eps)
    else:
        cum = np.cumsum(powers) / total_power
        which = np.minimum(np.searchsorted(cum, u[:, 0], side="right"), len(powers) - 1)
        for s, src in enumerate(spec.sources):
            sel = which == s
            if sel.any():
                o[sel], d[sel] = _emit(src, u[sel, 1:5], spec.eps)
    idx = np.arange(n)
    w = np.full(n, w0)
    prev_kind = np.zeros(n, dtype=np.int8)
    pdf_prev = np.zeros(n)  # solid-angle pdf of the last sampled scatter direction (for NEE MIS weights)
    prev_part = np.full(n, -1, dtype=np.int64)
    hkey = np.zeros(n, dtype=np.uint64)
    depth = np.zeros(n, dtype=np.int64)
    hist = np.full((n, K), -1, dtype=np.int16) if opt.record_paths else None
    k_nee = int(opt.nee_samples)
    n_uniform = 4 + 3 * D * k_nee + (4 if comp.target is not None else 0)
    tcol = 4 + 3 * D * k_nee
    segments = 0
    shadow_rays = 0

    def record(det_j, ray_local, pts, power, keys, events, dep):
        if len(ray_local) == 0:
            return
        b = comp.detectors[det_j].bin_index(pts, bins)
        map_rows.append((ray_local, np.full(len(ray_local), det_j), b, power))
        if opt.record_paths:
            path_rows.append((ray_local, np.full(len(ray_local), comp.det_parts[det_j], dtype=np.int16), power,
                              dep.astype(np.int16), keys, events))

    for ev in range(int(opt.max_events)):
        if len(idx) == 0:
            break
        counts = np.bincount(idx // C, minlength=nch)
        U = np.concatenate([gens[c].random((counts[c], n_uniform)) for c in range(nch) if counts[c]])
        tri = comp.isect.first_triangle(o, d)
        segments += len(idx)
        miss = tri < 0
        if miss.any():
            M[lay.ESC, idx[miss]] += w[miss]
            hit = ~miss
            idx, o, d, w, tri, U, pdf_prev = idx[hit], o[hit], d[hit], w[hit], tri[hit], U[hit], pdf_prev[hit]
            prev_kind, prev_part, hkey, depth = prev_kind[hit], prev_part[hit], hkey[hit], depth[hit]
            if hist is not None:
                hist = hist[hit]
            if len(idx) == 0:
                break
        part = spec.triangle_part[tri].astype(np.int64)
        role = spec.part_roles[part]
        ng = comp.normals[tri]
        cos_in = _dot(d, ng)
        # hit distance in float64 from the triangle's plane (embree found the triangle in float32)
        edge_on = np.abs(cos_in) < 1e-12
        t = (comp.plane_d[tri] - _dot(ng, o)) / np.where(edge_on, 1.0, cos_in)
        if edge_on.any():
            t[edge_on] = _dot(comp.centroids[tri[edge_on]] - o[edge_on], d[edge_on])
        p = o + np.maximum(t, 0.0)[:, None] * d
        nf = np.where((cos_in < 0)[:, None], ng, -ng)
        M[lay.INC + part, idx] += w
        first = prev_kind == 0
        M[lay.FIRST + part[first], idx[first]] += w[first]

        # detectors: record (unless covered by NEE) and end the ray
        isdet = role == _DETECTOR
        if isdet.any():
            sens = isdet & (both_sides | (cos_in < 0))
            dead = isdet & ~sens
            M[lay.ABS + part[dead], idx[dead]] += w[dead]
            dj = comp.det_of_part[part]
            M[lay.DET_WALK + dj[sens], idx[sens]] += w[sens]
            # a hit straight after a BRDF scatter is shared with NEE by MIS weights (power heuristic)
            covered = np.flatnonzero(sens & (prev_kind == KIND_SCATTER) & opt.nee)
            w_det = w.copy()
            if len(covered):
                p_n = k_nee * t[covered] ** 2 / (comp.det_area[dj[covered]] * np.abs(cos_in[covered]))
                w_b = _power_heuristic(pdf_prev[covered], p_n)
                w_det[covered] = w[covered] * w_b
                M[lay.NEX + prev_part[covered], idx[covered]] += w[covered] - w_det[covered]
            counted = sens & (w_det > 0)
            M[lay.DET_DIRECT + dj[counted], idx[counted]] += w_det[counted]
            for j in range(D):
                cj = np.flatnonzero(counted & (dj == j))
                if len(cj):
                    keys = mix_key(hkey[cj], comp.det_parts[j] * 4 + KIND_DETECTOR) if opt.record_paths else None
                    record(j, idx[cj], p[cj], w_det[cj], keys, None if hist is None else hist[cj].copy(), depth[cj])
        isabs = role == _ABSORBER
        M[lay.ABS + part[isabs], idx[isabs]] += w[isabs]

        # continuing rays
        cont = np.flatnonzero((role == _SURFACE) | (role == _MIRROR))
        if len(cont) == 0:
            idx = idx[:0]
            break
        if len(cont) < len(idx):
            idx, d, w, U, part, role, p, ng, nf, pdf_prev = (
                a[cont] for a in (idx, d, w, U, part, role, p, ng, nf, pdf_prev))
            prev_kind, prev_part, hkey, depth = prev_kind[cont], prev_part[cont], hkey[cont], depth[cont]
            if hist is not None:
                hist = hist[cont]
        w_new = np.zeros(len(idx))
        pdf_new = np.zeros(len(idx))
        kind = np.where(role == _SURFACE, KIND_SCATTER, KIND_SPECULAR).astype(np.int8)
        mir = np.flatnonzero(role == _MIRROR)
        d_new = np.empty_like(d)
        if len(mir):  # specular reflection about the geometric normal
            d_new[mir] = d[mir] - 2.0 * _dot(d[mir], nf[mir])[:, None] * nf[mir]
            w_new[mir] = w[mir] * float(opt.mirror_reflectance)
        code = part * 4 + kind
        surf = np.flatnonzero(role == _SURFACE)
        n_surf = len(surf)
        if n_surf == len(idx):
            surf = slice(None)  # every hit scatters: views instead of copies
        if n_surf:
            tb, bb = orthonormal_basis(nf[surf])
            wi = -d[surf]
            wi_loc = np.stack([_dot(wi, tb), _dot(wi, bb), _dot(wi, nf[surf])], axis=-1)
            mat = spec.part_material[part[surf]]
            o_off = p[surf] + spec.eps * nf[surf]
            if opt.nee and D:
                keys_v = mix_key(hkey[surf], code[surf]) if opt.record_paths else None
                for jk in range(D * k_nee):
                    j = jk // k_nee
                    geo = comp.detectors[j]
                    y, ny = geo.sample(U[surf, 4 + 3 * jk: 7 + 3 * jk])
                    v = y - p[surf]
                    dist2 = _dot(v, v)
                    dist = np.sqrt(dist2)
                    wdir = v / np.where(dist > 0, dist, 1.0)[:, None]
                    cos_s = _dot(wdir, nf[surf])
                    cos_d = -_dot(wdir, ny)
                    if both_sides:
                        cos_d = np.abs(cos_d)
                    ok = np.flatnonzero((cos_s > 0) & (cos_d > 0) & (dist > 2 * spec.eps))
                    if len(ok) == 0:
                        continue
                    wo_loc = np.stack([_dot(wdir[ok], tb[ok]), _dot(wdir[ok], bb[ok]), cos_s[ok]], axis=-1)
                    f = np.zeros(len(ok))
                    p_b = np.zeros(len(ok))
                    for m in np.unique(mat[ok]):
                        sel = mat[ok] == m
                        model = spec.materials[m]
                        f[sel] = model.brdf(wi_loc[ok][sel], wo_loc[sel], opt.polarization)
                        p_b[sel] = model.pdf(wi_loc[ok][sel], wo_loc[sel], opt.polarization)
                    if comp.target is not None:
                        q = float(opt.target_fraction)
                        p_b = (1 - q) * p_b + q * _target_pdf(comp, p[surf][ok], nf[surf][ok], wdir[ok], spec.eps)
                    # MIS with the walk's own hits on the detector (power heuristic, Veach 1997 ch. 9)
                    # (k shadow rays per vertex: each counts 1/k, MIS density k p_n)
                    p_n = k_nee * dist2[ok] / (geo.area_mm2 * cos_d[ok])
                    c = (w[surf][ok] * f * cos_s[ok] * cos_d[ok] * geo.area_mm2 / dist2[ok]
                         * _power_heuristic(p_n, p_b) / k_nee)
                    pos = c > 0
                    ok, c = ok[pos], c[pos]
                    if len(ok) == 0:
                        continue
                    vo = y[ok] - o_off[ok]
                    lo = np.sqrt(_dot(vo, vo))
                    blocked = comp.isect.occluded(o_off[ok], vo / lo[:, None], lo - spec.eps)
                    shadow_rays += len(ok)
                    ok, c = ok[~blocked], c[~blocked]
                    rows = idx[surf][ok]
                    M[lay.DET_NEE + j, rows] += c
                    M[lay.NEX + part[surf][ok], rows] -= c
                    ev_rows = None
                    if hist is not None:
                        ev_rows = hist[surf][ok].copy()
                        dd = depth[surf][ok]
                        inside = dd < K
                        ev_rows[np.flatnonzero(inside), dd[inside]] = code[surf][ok][inside]
                    keys = mix_key(keys_v[ok], comp.det_parts[j] * 4 + KIND_DETECTOR) if opt.record_paths else None
                    record(j, rows, y[ok], c, keys, ev_rows, depth[surf][ok] + 1)
            if len(spec.materials) == 1:
                groups = [(0, slice(None))]
            else:
                groups = [(m, mat == m) for m in np.unique(mat)]
            wo_world = np.empty((n_surf, 3))
            weight = np.empty(n_surf)
            pdf_dir = np.empty(n_surf)
            nfs = nf[surf]
            for m, sel in groups:
                smp = spec.materials[m].sample(wi_loc[sel], U[surf][sel, 0:3], opt.polarization)
                wo = np.asarray(smp.wo, dtype=np.float64)
                weight[sel] = np.where(wo[:, 2] > 0, np.asarray(smp.weight, dtype=np.float64), 0.0)
                pdf_dir[sel] = smp.pdf_per_sr
                wo_world[sel] = wo[:, :1] * tb[sel] + wo[:, 1:2] * bb[sel] + wo[:, 2:3] * nfs[sel]
            norm = np.linalg.norm(wo_world, axis=1, keepdims=True)
            wo_world = wo_world / np.where(norm > 0, norm, 1.0)
            if comp.target is not None:
                wo_world, weight, pdf_dir = _target_mixture(spec, comp, opt, U[surf, tcol:tcol + 4], p[surf], nfs,
                                                            tb, bb, wi_loc, wo_world, mat, groups)
            d_new[surf] = wo_world
            w_new[surf] = w[surf] * weight
            pdf_new[surf] = pdf_dir
        M[lay.ABS + part, idx] += w - w_new
        # Russian roulette (unbiased): survive with probability w_new / thr at weight thr
        low = (w_new < thr) & (w_new > 0)
        w_after = w_new.copy()
        if low.any():
            survive = U[low, 3] * thr < w_new[low]
            w_after[low] = np.where(survive, thr, 0.0)
            M[lay.RR + part[low], idx[low]] += w_new[low] - w_after[low]
        alive = w_after > 0
        if ev == int(opt.max_events) - 1:
            M[lay.TRUNC + part[alive], idx[alive]] += w_after[alive]
            idx = idx[:0]
            break
        keep = np.flatnonzero(alive)
        if hist is not None:
            hist = hist[keep]
            dk = depth[keep]
            inside = dk < K
            hist[np.flatnonzero(inside), dk[inside]] = code[keep][inside]
        idx = idx[keep]
        o = p[keep] + spec.eps * nf[keep]
        d = d_new[keep]
        w = w_after[keep]
        prev_kind = kind[keep]
        pdf_prev = pdf_new[keep]
        prev_part = part[keep]
        if opt.record_paths:  # path hashes are only needed for path records
            hkey = mix_key(hkey[keep], code[keep])
        else:
            hkey = hkey[keep]
        depth = depth[keep] + 1

    return _batch_sums(M, lay, D, n, nch, start, first_chunk, bins, map_rows, path_rows, opt, segments, shadow_rays,
                       compiled=False)


def _batch_sums(M, lay, D, n, nch, start, first_chunk, bins, map_rows, path_rows, opt, segments, shadow_rays,
                compiled=True, clear=False):
    """Per-chunk sums S1, S2 of every tally row (chunk order, fixed chunk length: independent of the
    batch size), irradiance-map sums and path records of one batch (``clear``: leave M all zeros)."""
    C = CHUNK_RAYS
    if compiled:
        from straylight._kernels import chunk_sums

        s1, s2 = chunk_sums(M, C, lay.P, D, lay.ABS, lay.RR, lay.NEX, lay.TRUNC, lay.DET_NEE, lay.DET_DIRECT,
                            clear)
    else:
        ledger = (M[lay.ABS:lay.ABS + lay.P] + M[lay.RR:lay.RR + lay.P]
                  + M[lay.NEX:lay.NEX + lay.P] + M[lay.TRUNC:lay.TRUNC + lay.P])
        det_total = M[lay.DET_NEE:lay.DET_NEE + D] + M[lay.DET_DIRECT:lay.DET_DIRECT + D]
        ext = np.concatenate([M, ledger, det_total], axis=0)
        starts = np.arange(0, n, C)
        s1 = np.add.reduceat(ext, starts, axis=1).T.copy()
        s2 = np.add.reduceat(ext * ext, starts, axis=1).T.copy()
    maps = _chunk_maps(map_rows, nch, C, D, bins)
    paths = None
    if opt.record_paths and path_rows:
        cols = [np.concatenate(x) for x in zip(*path_rows)]
        order = np.lexsort((cols[1], cols[3], cols[0]))
        paths = {
            "ray": cols[0][order] + start, "detector": cols[1][order], "power_w": cols[2][order],
            "depth": cols[3][order], "key": cols[4][order], "events": cols[5][order],
        }
    return {"first_chunk": first_chunk, "s1": s1, "s2": s2, "maps": maps, "paths": paths,
            "segments": segments, "shadow_rays": shadow_rays}


def _draw_uniforms(streams, idx, width, buf=None):
    """This event's uniforms of the live rays (ascending ids): chunk k draws (live rays in k, width)
    from its stream (compiled, :class:`straylight.rng.ChunkStreams`), written in place into ``buf``
    (flat float64 scratch of at least len(idx) * width) when given."""
    m = len(idx)
    U = np.empty((m, width)) if buf is None else buf[:m * width].reshape(m, width)
    return streams.fill(idx, width, U, CHUNK_RAYS)


def _emit_batch(spec, streams, n, buf=None):
    """Emission: chunk k draws (rays in chunk, 5) uniforms first; returns origins, directions (n, 3)."""
    u = np.empty((n, 5)) if buf is None else buf[:n * 5].reshape(n, 5)
    streams.fill(np.arange(n, dtype=np.int64), 5, u, CHUNK_RAYS)
    if len(spec.sources) == 1:
        o, d = _emit(spec.sources[0], u[:, 1:5], spec.eps)
    else:
        powers = np.array([s.power_w for s in spec.sources], dtype=np.float64)
        o = np.empty((n, 3))
        d = np.empty((n, 3))
        cum = np.cumsum(powers) / float(powers.sum())
        which = np.minimum(np.searchsorted(cum, u[:, 0], side="right"), len(powers) - 1)
        for s, src in enumerate(spec.sources):
            sel = which == s
            if sel.any():
                o[sel], d[sel] = _emit(src, u[sel, 1:5], spec.eps)
    o = np.ascontiguousarray(o, dtype=np.float64)
    d = np.ascontiguousarray(d, dtype=np.float64)
    if buf is not None and np.may_share_memory(d, buf):  # a source that returns views of its uniforms:
        d = d.copy()  # the scratch is refilled every event
    if buf is not None and np.may_share_memory(o, buf):
        o = o.copy()
    return o, d


def _by_material(spec, mat, call):
    """Evaluate ``call(model, rows)`` per material over the rows of ``mat`` (material index per row);
    returns the list of (rows, result); rows is a slice when one material covers everything."""
    if len(spec.materials) == 1:
        return [(slice(None), call(spec.materials[0], slice(None)))]
    out = []
    for m in np.unique(mat):
        sel = np.flatnonzero(mat == m)
        out.append((sel, call(spec.materials[m], sel)))
    return out


def run_batch(spec: TraceSpec, first_chunk: int, stop_chunk: int, intersector=None) -> dict:
    """Trace chunks ``first_chunk .. stop_chunk-1``; returns per-chunk sums (see :func:`trace`).

    The per-vertex work runs in compiled kernels (:mod:`straylight._kernels`); materials, sources,
    random draws and ray casts are called once per event on contiguous arrays.
    :func:`run_batch_reference` is the numpy twin it is tested against (bit-identical).
    """
    from straylight import _kernels as kern

    comp = _compiled(spec, intersector)
    opt = spec.options
    lay = _Layout(len(spec.part_names), len(comp.det_parts))
    C = CHUNK_RAYS
    start = first_chunk * C
    stop = min(stop_chunk * C, spec.n_rays)
    n = stop - start
    nch = stop_chunk - first_chunk
    streams = ChunkStreams(spec.seed, first_chunk, stop_chunk)  # chunk_rng's streams, compiled
    total_power = float(sum(s.power_w for s in spec.sources))
    w0 = total_power / spec.n_rays
    thr = opt.rr_threshold * w0
    M = comp.tally_buffer(lay.n, n)  # per-ray tallies, one row per tally (zeroed, reused)
    D = len(comp.det_parts)
    K = int(opt.path_depth)
    bins = tuple(int(b) for b in opt.map_bins)
    both_sides = opt.detector_sides == "both"
    nee = bool(opt.nee) and D > 0
    record_paths = bool(opt.record_paths)
    pol = opt.polarization
    map_rows, path_rows = [], []

    n_uniform = 4 + 3 * D * int(opt.nee_samples) + (4 if comp.target is not None else 0)
    ubuf = comp.scratch("uniforms", n * max(5, n_uniform))  # this thread's draws, refilled every event
    o, d = _emit_batch(spec, streams, n, ubuf)
    idx = np.arange(n, dtype=np.int64)
    w = np.full(n, w0)
    prev_kind = np.zeros(n, dtype=np.int8)
    pdf_prev = np.zeros(n)  # solid-angle pdf of the last sampled scatter direction (for NEE MIS weights)
    prev_part = np.full(n, -1, dtype=np.int64)
    hkey = np.zeros(n, dtype=np.uint64)
    depth = np.zeros(n, dtype=np.int64)
    hist = np.full((n if record_paths else 0, K), -1, dtype=np.int16)
    k_nee = int(opt.nee_samples)
    tcol = 4 + 3 * D * k_nee
    segments = 0
    shadow_rays = 0
    max_events = int(opt.max_events)
    table = spec.vertex_table if D > 0 else None
    w_first = np.ones(n) if table is not None else None  # forward MIS weight of each ray's first vertex

    def record(det_j, ray_local, pts, power, keys, events, dep):
        if len(ray_local) == 0:
            return
        b = comp.detectors[det_j].bin_index(pts, bins)
        map_rows.append((ray_local, np.full(len(ray_local), det_j), b, power))
        if record_paths:
            path_rows.append((ray_local, np.full(len(ray_local), comp.det_parts[det_j], dtype=np.int16), power,
                              dep.astype(np.int16), keys, events))

    for ev in range(max_events):
        if len(idx) == 0:
            break
        U = _draw_uniforms(streams, idx, n_uniform, ubuf)
        tri = np.asarray(comp.isect.first_triangle(o, d))
        segments += len(idx)
        cont, p, nf, part, t, cos_in, rec, rec_w = kern.hits(
            tri, o, d, w, idx, prev_kind, pdf_prev, prev_part, spec.triangle_part, spec.part_roles, comp.normals,
            comp.plane_d, comp.centroids, comp.det_of_part, comp.det_area, both_sides, bool(opt.nee), k_nee, M,
            lay.ESC, lay.INC, lay.FIRST, lay.ABS, lay.DET_WALK, lay.NEX, lay.DET_DIRECT)
        if len(rec) and table is not None:
            rec, rec_w = _share_single_scatter(rec, rec_w, prev_kind, depth, prev_part, part, idx, w_first, comp, M,
                                               lay)
        if len(rec):  # counted random-walk hits on detectors
            dj = comp.det_of_part[part[rec]]
            for j in range(D):
                sel = dj == j
                if sel.any():
                    r = rec[sel]
                    keys = mix_key(hkey[r], comp.det_parts[j] * 4 + KIND_DETECTOR) if record_paths else None
                    record(j, idx[r], p[r], rec_w[sel], keys, hist[r] if record_paths else None, depth[r])
        if len(cont) == 0:
            idx = idx[:0]
            break
        surf, surf_of, tb, bb, wi_loc, mat, u_s = kern.frames(cont, d, nf, part, spec.part_roles, spec.part_material,
                                                              U)
        n_surf = len(surf)
        wo_world, weight, pdf_dir = np.zeros((0, 3)), np.zeros(0), np.zeros(0)
        if n_surf:
            ii = cont[surf]
            w_vertex = None
            if table is not None:
                first = np.flatnonzero(prev_kind[ii] == 0)
                if len(first):
                    from straylight.first_vertex import forward_weight

                    w_vertex = np.ones(n_surf)
                    w_vertex[first] = forward_weight(spec, table, comp.normals, tri[ii[first]], p[ii[first]])
                    w_first[idx[ii[first]]] = w_vertex[first]
            if nee:
                ps, pjk, y, wo_loc, dist2, cos_s, cos_d, wdir = kern.nee_pairs(
                    cont, surf, tb, bb, p, nf, U, 4, D, k_nee, comp.det_off, comp.det_prob, comp.det_alias,
                    comp.det_v0, comp.det_e1, comp.det_e2, comp.det_normals, both_sides, spec.eps)
                if len(ps):
                    f = np.empty(len(ps))
                    p_b = np.empty(len(ps))
                    # materials see the same arrays as in the numpy engine: one call per (detector,
                    # sample) and material, rays in order (vectorised transcendental functions may
                    # round differently in a block's tail)
                    for jk in range(D * k_nee):
                        sel_jk = np.flatnonzero(pjk == jk) if D * k_nee > 1 else slice(None)
                        wi_p = wi_loc[ps[sel_jk]]
                        wo_p = wo_loc[sel_jk]
                        fj = np.empty(len(wi_p))
                        pj = np.empty(len(wi_p))
                        for rows, (fv, pv) in _by_material(spec, mat[ps[sel_jk]], lambda model, rows: (
                                model.brdf(wi_p[rows], wo_p[rows], pol), model.pdf(wi_p[rows], wo_p[rows], pol))):
                            fj[rows] = fv
                            pj[rows] = pv
                        if comp.target is not None:
                            q = float(opt.target_fraction)
                            jp = ii[ps[sel_jk]]
                            pj = (1 - q) * pj + q * _target_pdf(comp, p[jp], nf[jp], wdir[sel_jk], spec.eps)
                        f[sel_jk] = fj if w_vertex is None else fj * w_vertex[ps[sel_jk]]
                        p_b[sel_jk] = pj
                    keep, cc, so, sd, tmax = kern.nee_shadow(ps, pjk, y, dist2, cos_s, cos_d, f, p_b, cont, surf, w,
                                                             p, nf, k_nee, comp.det_area, spec.eps)
                    if len(keep):
                        blocked = np.asarray(comp.isect.occluded(so, sd, tmax), dtype=bool)
                        shadow_rays += len(keep)
                        okb = kern.nee_tally(keep, cc, blocked, ps, pjk, cont, surf, idx, part, k_nee, M,
                                             lay.DET_NEE, lay.NEX)
                        if len(okb):
                            _record_nee(record, okb, keep, cc, ps, pjk, y, ii, idx, part, hkey, depth, hist, k_nee, D,
                                        K, comp, record_paths)
            wo = np.empty((n_surf, 3))
            wraw = np.empty(n_surf)
            pdf_dir = np.empty(n_surf)
            for rows, smp in _by_material(spec, mat, lambda model, rows: model.sample(wi_loc[rows], u_s[rows], pol)):
                wo[rows] = smp.wo
                wraw[rows] = smp.weight
                pdf_dir[rows] = smp.pdf_per_sr
            wo_world, weight, pdf_dir = kern.to_world(wo, wraw, pdf_dir, tb, bb, surf, cont, nf)
            if comp.target is not None:
                groups = [(0, slice(None))] if len(spec.materials) == 1 else [(m, mat == m) for m in np.unique(mat)]
                wo_world, weight, pdf_dir = _target_mixture(spec, comp, opt, U[ii, tcol:tcol + 4], p[ii], nf[ii],
                                                            tb, bb, wi_loc, wo_world, mat, groups)
        idx, o, d, w, prev_kind, pdf_prev, prev_part, hkey, depth, hist = kern.advance(
            cont, surf_of, np.ascontiguousarray(wo_world).reshape(-1, 3), np.ascontiguousarray(weight, np.float64),
            np.ascontiguousarray(pdf_dir, np.float64), d, w, p, nf, part, idx, U, hkey, depth, hist, record_paths,
            record_paths, float(opt.mirror_reflectance), thr, spec.eps, ev == max_events - 1, M, lay.ABS, lay.RR,
            lay.TRUNC)

    if table is not None:
        from straylight.first_vertex import run_vertex_pass

        shadow_rays += run_vertex_pass(spec, comp, table, first_chunk, stop_chunk, M, lay, record, record_paths, K)
    out = _batch_sums(M, lay, D, n, nch, start, first_chunk, bins, map_rows, path_rows, opt, segments, shadow_rays,
                      clear=True)
    comp.tally_cleared()
    return out


def _share_single_scatter(rec, rec_w, prev_kind, depth, prev_part, part, idx, w_first, comp, M, lay):
    """Walk hits on a detector straight after a ray's first (scatter) event keep only their forward
    MIS share ``w_first`` (the rest is the vertex-sampling strategy's); the remainder goes to the
    NEE exchange, so the ledger stays exact."""
    single = np.flatnonzero((prev_kind[rec] == KIND_SCATTER) & (depth[rec] == 1))
    if len(single) == 0:
        return rec, rec_w
    i = rec[single]
    r = idx[i]
    moved = rec_w[single] * (1.0 - w_first[r])
    M[lay.DET_DIRECT + comp.det_of_part[part[i]], r] -= moved
    M[lay.NEX + prev_part[i], r] += moved
    rec_w = rec_w.copy()
    rec_w[single] -= moved
    keep = rec_w > 0
    return rec[keep], rec_w[keep]


def _record_nee(record, okb, keep, cc, ps, pjk, y, ii, idx, part, hkey, depth, hist, k_nee, D, K, comp, record_paths):
    """Map (and path) records of the unblocked NEE contributions, per detector."""
    a = keep[okb]
    c = cc[okb]
    live = ii[ps[a]]
    jk_a = pjk[a]
    # one record call per (detector, sample), as the numpy engine makes them: the map binning
    # (a BLAS product) then sees the same arrays, so the bins are the same to the last bit
    for jk in range(D * k_nee):
        j = jk // k_nee
        sel = np.flatnonzero(jk_a == jk)
        if len(sel) == 0:
            continue
        i = live[sel]
        keys = ev_rows = None
        if record_paths:
            code = part[i] * 4 + KIND_SCATTER
            keys = mix_key(mix_key(hkey[i], code), comp.det_parts[j] * 4 + KIND_DETECTOR)
            ev_rows = hist[i]
            dd = depth[i]
            inside = np.flatnonzero(dd < K)
            ev_rows[inside, dd[inside]] = code[inside]
        record(j, idx[i], y[a[sel]], c[sel], keys, ev_rows, depth[i] + 1)


def _target_mixture(spec, comp, opt, ut, p, nf, tb, bb, wi_loc, wo_world, mat, groups):
    """One-sample MIS between BRDF sampling and area sampling of the (flat) target parts.

    With probability q = target_fraction the direction points at a uniform point of the target
    (pdf per sr: d^2 / (A |cos_y|)), else it is the BRDF draw already in ``wo_world``. Either way
    the weight is f cos / ((1 - q) pdf_brdf + q pdf_target) (balance heuristic; Veach 1997, ch. 9).
    """
    q = float(opt.target_fraction)
    use_t = ut[:, 0] < q
    wo_world = wo_world.copy()
    if use_t.any():
        y, _ = comp.target.sample(ut[use_t, 1:4])
        v = y - p[use_t]
        wo_world[use_t] = v / np.linalg.norm(v, axis=1, keepdims=True)
    wo_loc = np.stack([_dot(wo_world, tb), _dot(wo_world, bb), _dot(wo_world, nf)], axis=-1)
    f = np.zeros(len(p))
    pdf_b = np.zeros(len(p))
    for m, sel in groups:
        f[sel] = spec.materials[m].brdf(wi_loc[sel], wo_loc[sel], opt.polarization)
        pdf_b[sel] = spec.materials[m].pdf(wi_loc[sel], wo_loc[sel], opt.polarization)
    mix = (1.0 - q) * pdf_b + q * _target_pdf(comp, p, nf, wo_world, spec.eps)
    cos_o = wo_loc[:, 2]
    good = (cos_o > 0) & (mix > 0)
    weight = np.where(good, f * cos_o / np.where(good, mix, 1.0), 0.0)
    return wo_world, weight, np.where(good, mix, 0.0)


def _target_pdf(comp, p, nf, dirs, eps):
    """Solid-angle density of area-sampling the flat target toward ``dirs`` from ``p``: d^2 / (A |cos_y|)."""
    tri_t = comp.target_isect.first_triangle(p + eps * nf, dirs)
    hit = np.flatnonzero(tri_t >= 0)
    pdf_t = np.zeros(len(p))
    if len(hit):
        nt = comp.target.normals[tri_t[hit]]
        cos_y = _dot(dirs[hit], nt)
        ok = np.abs(cos_y) > 1e-12
        dist = (comp.target_plane_d[tri_t[hit]] - _dot(nt, p[hit])) / np.where(ok, cos_y, 1.0)
        pdf_t[hit] = np.where(ok, dist * dist / (comp.target.area_mm2 * np.abs(np.where(ok, cos_y, 1.0))), 0.0)
    return pdf_t


def _power_heuristic(p_this, p_other):
    """MIS weight p^2 / (p^2 + q^2) of the strategy with density p_this (Veach 1997, eq. 9.13)."""
    a = np.asarray(p_this, dtype=np.float64) ** 2
    b = np.asarray(p_other, dtype=np.float64) ** 2
    total = a + b
    return np.where(total > 0, a / np.where(total > 0, total, 1.0), 0.0)


def _chunk_maps(map_rows, nch, C, D, bins):
    """Per chunk and detector: (bin indices, sum of power, sum over rays of (ray's power in bin)^2)."""
    nb = bins[0] * bins[1]
    out = [[None] * D for _ in range(nch)]
    if not map_rows:
        return out
    from straylight._kernels import map_sums

    ray, det, b, pw = (np.concatenate(x) for x in zip(*map_rows))
    # one key per (ray, detector, bin); sorting makes the sums independent of record order
    key = (ray.astype(np.int64) * D + det) * nb + b
    order = np.argsort(key, kind="stable")
    chunk, dj, bins_, s1, s2, g_start, g_stop = map_sums(key[order], np.ascontiguousarray(pw[order], np.float64),
                                                         nb, D, C)
    for a, z in zip(g_start.tolist(), g_stop.tolist()):
        out[int(chunk[a])][int(dj[a])] = (bins_[a:z], s1[a:z], s2[a:z])
    return out


# ------------------------------------------------------------------ results


@dataclass(frozen=True, eq=False)
class TraceResult:
    """Outcome of :func:`trace`; see docs/engine.md for each field."""

    n_rays: int
    seed: int
    emitted_w: float
    detectors: dict
    maps: dict
    absorbed: dict
    escaped: Tally
    incident: dict
    first_hit: dict
    ledger: dict
    paths: PathRecords | None
    segments: int
    shadow_rays: int

    def to_json_dict(self) -> dict:
        """CONTRACTS §4.3 keys, plus the ledger breakdown (its terms are already inside ``absorbed``)."""
        led = self.ledger
        return {
            "rays": self.n_rays,
            "seed": self.seed,
            "emitted_w": self.emitted_w,
            "detectors": {k: v.to_dict() for k, v in self.detectors.items()},
            "absorbed": {k: v.to_dict() for k, v in self.absorbed.items()},
            "escaped_w": self.escaped.power_w,
            "escaped_stderr_w": self.escaped.stderr_w,
            "ledger": {
                "note": "roulette, nee_exchange and truncated are already included in 'absorbed'; "
                        "emitted_w = sum(detectors) + sum(absorbed) + escaped_w",
                "roulette_w": led["roulette_w"].power_w,
                "roulette_stderr_w": led["roulette_w"].stderr_w,
                "nee_exchange_w": led["nee_exchange_w"].power_w,
                "truncated_w": led["truncated_w"].power_w,
                "balance_residual_w": led["balance_residual_w"],
                "detector_walk": {k: v.to_dict() for k, v in led["detector_walk"].items()},
                "absorbed_physical": {k: v.to_dict() for k, v in led["absorbed_physical"].items()},
            },
            "segments": self.segments,
            "shadow_rays": self.shadow_rays,
        }


def _build_result(spec: TraceSpec, comp_dets, s1, s2, map_sums, paths_pieces, segments, shadow) -> TraceResult:
    N = spec.n_rays
    err = stderr_from_sums(s1, s2, N)
    names = spec.part_names
    P = len(names)
    det_parts = spec.detector_parts
    D = len(det_parts)
    lay = _Layout(P, D)

    def tally(row):
        return Tally(float(s1[row]), float(err[row]))

    def summed(base):
        rows = slice(base, base + P)
        tot = float(s1[rows].sum())
        # per-ray sums of a whole block are not kept; the block's stderr adds per-part variances
        return Tally(tot, float(np.sqrt(np.sum(err[rows] ** 2))))

    detectors = {names[p]: tally(lay.DET_TOTAL + j) for j, p in enumerate(det_parts)}
    show_abs = [i for i in range(P) if spec.part_roles[i] != _DETECTOR or spec.options.detector_sides == "front"]
    absorbed = {names[i]: tally(lay.LEDGER_ABS + i) for i in show_abs}
    escaped = tally(lay.ESC)
    emitted = float(sum(s.power_w for s in spec.sources))
    residual = emitted - (sum(t.power_w for t in detectors.values()) + sum(t.power_w for t in absorbed.values())
                          + escaped.power_w)
    ledger = {
        "absorbed_physical": {names[i]: tally(lay.ABS + i) for i in range(P)},
        "roulette": {names[i]: tally(lay.RR + i) for i in range(P)},
        "nee_exchange": {names[i]: tally(lay.NEX + i) for i in range(P)},
        "truncated": {names[i]: tally(lay.TRUNC + i) for i in range(P)},
        "detector_walk": {names[p]: tally(lay.DET_WALK + j) for j, p in enumerate(det_parts)},
        "detector_nee": {names[p]: tally(lay.DET_NEE + j) for j, p in enumerate(det_parts)},
        "detector_direct": {names[p]: tally(lay.DET_DIRECT + j) for j, p in enumerate(det_parts)},
        "roulette_w": summed(lay.RR),
        "nee_exchange_w": summed(lay.NEX),
        "truncated_w": summed(lay.TRUNC),
        "balance_residual_w": float(residual),
    }
    maps = {}
    bins = tuple(int(b) for b in spec.options.map_bins)
    for j, p in enumerate(det_parts):
        geo = comp_dets[j]
        m1, m2 = map_sums[j]
        eu, ev = geo.edges_mm(bins)
        maps[names[p]] = IrradianceMap(eu, ev, m1.reshape(bins), stderr_from_sums(m1, m2, N).reshape(bins),
                                       geo.origin_mm, geo.axis_u, geo.axis_v, geo.normal)
    paths = None
    if spec.options.record_paths:
        paths = PathRecords.concatenate(paths_pieces, names, N, int(spec.options.path_depth))
    return TraceResult(
        n_rays=N, seed=spec.seed, emitted_w=emitted, detectors=detectors, maps=maps, absorbed=absorbed,
        escaped=escaped,
        incident={names[i]: tally(lay.INC + i) for i in range(P)},
        first_hit={names[i]: tally(lay.FIRST + i) for i in range(P)},
        ledger=ledger, paths=paths, segments=int(segments), shadow_rays=int(shadow),
    )


# ------------------------------------------------------------------ spec


def _resolve_materials(scene, materials):
    """Material name -> model, for parts that scatter; returns (part_material (P,), models tuple)."""
    needed = sorted({p.material for p in scene.parts if p.role == "surface"}, key=str)
    models = []
    index = {}
    for name in needed:
        if name is None:
            bad = [p.name for p in scene.parts if p.role == "surface" and p.material is None]
            raise TraceError(f"surface part(s) {', '.join(bad)} have no material")
        if materials is not None and name in materials:
            model = materials[name]
        else:
            try:
                from materials import load_material
            except ImportError:
                known = ", ".join(sorted(materials)) if materials else "none given"
                raise TraceError(f"unknown material {name!r}; known: {known}") from None
            model = load_material(name)
        index[name] = len(models)
        models.append(model)
    part_material = np.array([index.get(p.material, -1) if p.role == "surface" else -1 for p in scene.parts],
                             dtype=np.int64)
    return part_material, tuple(models)


AUTO_BATCH_MAX_RAYS = 50_000
TALLY_BUDGET_BYTES = 32_000_000


def auto_batch_rays(n_rows: int) -> int:
    """Rays per in-memory batch: as many as amortise the per-call overheads (up to
    AUTO_BATCH_MAX_RAYS; 50k ran ~10 % faster than 20k on the reference tube) while the per-ray
    tally matrix (n_rows x batch float64) stays under TALLY_BUDGET_BYTES. Never changes results."""
    fit = TALLY_BUDGET_BYTES // (8 * max(int(n_rows), 1))
    return int(max(CHUNK_RAYS, min(AUTO_BATCH_MAX_RAYS, fit // CHUNK_RAYS * CHUNK_RAYS)))


def make_spec(scene, sources, n_rays, seed=0, materials=None, options=None) -> TraceSpec:
    """Check inputs and build the picklable :class:`TraceSpec` used by :func:`run_batch`."""
    options = options or TraceOptions()
    seed = check_seed(seed)
    if isinstance(n_rays, bool) or not isinstance(n_rays, (int, np.integer)) or int(n_rays) < 1:
        raise TraceError(f"n_rays must be a positive integer, got {n_rays!r}")
    if not isinstance(sources, (list, tuple)):
        sources = (sources,)
    if not sources:
        raise TraceError("at least one source is needed")
    if sum(s.power_w for s in sources) <= 0:
        raise TraceError("total source power_w must be > 0")
    part_material, models = _resolve_materials(scene, materials)
    for name in options.target_parts:
        if name not in scene.part_names:
            raise TraceError(f"target part {name!r} not in the scene; parts: {', '.join(scene.part_names)}")
    if options.target_parts:
        ttri = np.concatenate([scene.part(n).vertices_mm[scene.part(n).faces] for n in options.target_parts])
        geo = DetectorGeometry.from_triangles(ttri)
        off = np.abs((ttri.reshape(-1, 3) - geo.origin_mm) @ geo.normal).max()
        size = float(np.ptp(ttri.reshape(-1, 3), axis=0).max())
        if off > 1e-6 * max(size, 1.0):
            raise TraceError(f"target parts {', '.join(options.target_parts)} must be flat (coplanar): "
                             f"vertices lie up to {off:.3g} mm off their plane")
    if options.first_vertex_sampling:
        from straylight.first_vertex import unsupported

        why = unsupported(tuple(sources))
        if why:
            raise TraceError(why)
    tri = np.ascontiguousarray(scene.triangles_mm, dtype=np.float64)
    tri_part = np.ascontiguousarray(scene.triangle_part, dtype=np.int32)
    roles = np.array([ROLE_CODES[p.role] for p in scene.parts], dtype=np.int64)
    h = hashlib.sha1(tri.tobytes())
    h.update(tri_part.tobytes())
    h.update(roles.tobytes())  # detector geometry depends on the roles,
    h.update(repr(options.target_parts).encode())  # and the target sampler on the targets
    return TraceSpec(
        triangles_mm=tri, triangle_part=tri_part, part_names=scene.part_names, part_roles=roles,
        part_material=part_material, materials=models, sources=tuple(sources), n_rays=int(n_rays), seed=seed,
        options=options, eps=scene_epsilon(tri), token=h.hexdigest(),
    )


class _NoIsect:
    """Placeholder so that detector geometry can be built without an embree scene."""
