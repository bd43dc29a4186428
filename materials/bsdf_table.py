"""Measured BSDF table imported from a Zemax/Radiant ``.bsdf`` or a FRED tabulated file.

Keys (material file, CONTRACTS §5 "further component types"; docs/bsdf-files.md)::

    {"type": "bsdf_table",
     "scatter": "brdf",                 # or "btdf" (theta_r measured from the -normal side)
     "symmetry": "plane",               # "plane": mirror-symmetric about the plane of incidence;
                                        # "none": the file gave both sides (Asymmetrical*)
     "rotation_deg": [0],               # sample rotations (Zemax SampleRotation), increasing
     "theta_i_deg": [10, 30, 50, 70],   # specular angles, increasing, in [0, 90)
     "blocks": [                        # len(rotation_deg) * len(theta_i_deg), rotation-major
        {"theta_r_deg": [...], "phi_r_deg": [...], "bsdf_per_sr": [...]}, ...],
     "tis": [...]}                      # optional: the file's own TIS lines (reported, never used)

Each block holds the file's nodes for one (rotation, incidence) as directions in the incidence
frame of CONTRACTS §1 (phi_r = 0 the specular half-plane). Nodes below the horizon are dropped.

Interpolation (the file's specular-centred coordinates, as FRED's beta - beta0 space): a node is
placed at ``d = beta - beta0`` (projected offset from the specular direction). Within a block the
value at a query offset is the barycentric (Delaunay) interpolation of the three nodes around it,
on log10(BSDF) where all three are positive and linear otherwise (so each node is reproduced
exactly); outside the nodes' hull the nearest node's value is held. A block whose nodes lie in the
plane of incidence only (FRED in-plane scans) is interpolated along the signed offset and extended
out of plane by |beta - beta0| (the isotropic beta - beta0 rule of FRED and materials.tabulated).
Between incidence blocks (and between sample rotations, periodically) values are blended
geometrically where all are positive (linearly otherwise; never above the linear blend):
the offset is carried to each block unchanged near the specular point and stretched so the horizon
meets the block's horizon (:func:`_to_block`).

Rotation: the sample frame is the part's local frame (x, y on the surface, z the normal). A ray
whose specular direction has azimuth phi_s in that frame sees the file's rotation
``phi_s - 90 deg`` (Zemax: the rotation is the angle between the normal of the plane of
incidence and the sample's +X axis). ``material eval --rotation-deg R`` evaluates at rotation R.

Sampling: half cosine-weighted, half a radial lobe about beta0 (materials.sampling, slope 2)
whose width is the narrowest half-width at half maximum of the blocks, as materials.tabulated.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass
from functools import cached_property
from typing import Optional

import numpy as np

from materials.albedo import directional_hemispherical_reflectance
from materials.base import MaterialError, Sample, check_polarization
from materials.flags import ComponentFlags
from materials.registry import register
from materials.sampling import (
    cosine_hemisphere_pdf,
    direction_uniforms,
    lobe_direction,
    lobe_pdf,
    sample_cosine_hemisphere,
)

_OWNER = "bsdf_table"


def _list(name, values, lo, hi, increasing=True):
    try:
        arr = np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        raise MaterialError(f"{_OWNER}: {name!r} must be a list of numbers") from None
    if arr.ndim != 1 or arr.size < 1:
        raise MaterialError(f"{_OWNER}: {name!r} must be a non-empty list of numbers")
    if not np.all(np.isfinite(arr)) or np.any(arr < lo) or np.any(arr > hi):
        raise MaterialError(f"{_OWNER}: {name!r} values must lie in [{lo}, {hi}]")
    if increasing and np.any(np.diff(arr) <= 0):
        raise MaterialError(f"{_OWNER}: {name!r} must be strictly increasing")
    return arr


class _Block:
    """Interpolant of one (rotation, incidence) block over offsets d = beta - beta0."""

    def __init__(self, theta_i, theta_r, phi_r, values, mirror):
        b0 = np.sin(theta_i)
        d = np.stack([np.sin(theta_r) * np.cos(phi_r) - b0, np.sin(theta_r) * np.sin(phi_r)], axis=-1)
        v = np.asarray(values, float)
        if mirror:
            d = np.concatenate([d, d * [1.0, -1.0]])
            v = np.concatenate([v, v])
        key = np.round(d, 9)
        uniq, inv = np.unique(key, axis=0, return_inverse=True)
        inv = inv.ravel()
        sums = np.zeros(len(uniq))
        np.add.at(sums, inv, v)
        counts = np.bincount(inv, minlength=len(uniq))
        self.d = uniq
        self.v = sums / counts
        self.in_plane = bool(np.all(np.abs(self.d[:, 1]) < 1e-9)) or len(self.d) < 3
        self.tri = None
        if not self.in_plane:
            from scipy.spatial import Delaunay, QhullError

            try:
                self.tri = Delaunay(self.d)
            except QhullError:
                self.in_plane = True
        if self.in_plane:
            order = np.argsort(self.d[:, 0])
            self.x = self.d[order, 0]
            self.xv = self.v[order]
        self._tree = None

    def _nearest(self, q):
        if self._tree is None:
            from scipy.spatial import cKDTree

            self._tree = cKDTree(self.d)
        return self.v[self._tree.query(q)[1]]

    def __call__(self, q):
        """Values at offsets q (n, 2)."""
        if self.in_plane:
            dist = np.hypot(q[:, 0], q[:, 1])
            s = np.where(q[:, 0] >= 0, 1.0, -1.0) * dist
            return _interp1(self.x, self.xv, s)
        simplex = self.tri.find_simplex(q)
        out = np.empty(len(q))
        inside = simplex >= 0
        if np.any(inside):
            qs = q[inside]
            sx = simplex[inside]
            trans = self.tri.transform[sx]
            b2 = np.einsum("nij,nj->ni", trans[:, :2, :], qs - trans[:, 2, :])
            bary = np.concatenate([b2, 1.0 - b2.sum(axis=1, keepdims=True)], axis=1)
            vv = self.v[self.tri.simplices[sx]]
            lin = np.sum(bary * vv, axis=1)
            pos = np.all(vv > 0, axis=1)
            logv = 10.0 ** np.sum(bary * np.log10(np.where(vv > 0, vv, 1.0)), axis=1)
            out[inside] = np.where(pos, logv, lin)
        if np.any(~inside):
            out[~inside] = self._nearest(q[~inside])
        return np.maximum(out, 0.0)


def _interp1(x, v, s):
    """1-D interpolation on log10 between positive neighbours, linear otherwise; edges held."""
    if len(x) == 1:
        return np.full(s.shape, v[0])
    s = np.clip(s, x[0], x[-1])
    j = np.clip(np.searchsorted(x, s, side="right") - 1, 0, len(x) - 2)
    t = (s - x[j]) / (x[j + 1] - x[j])
    a, b = v[j], v[j + 1]
    pos = (a > 0) & (b > 0)
    lin = (1 - t) * a + t * b
    lg = 10.0 ** ((1 - t) * np.log10(np.where(a > 0, a, 1.0)) + t * np.log10(np.where(b > 0, b, 1.0)))
    return np.where(pos, lg, lin)


def _edge(b, c, s):
    """Distance from beta0 = (b, 0) to the unit circle along the direction (c, s)."""
    return -b * c + np.sqrt(np.maximum(1.0 - (b * s) ** 2, 0.0))


def _to_block(d, theta_q_deg, theta_k_deg):
    """Offsets d at incidences theta_q carried to the block of incidence theta_k: unchanged near the
    specular point (a beta-centred lobe keeps its shape) and the horizon carried onto the block's
    horizon: rho_k = rho + (e_k - e_q) (rho / e_q)^2, e the distance from beta0 to the disk edge
    along d. The identity when theta_q = theta_k (so each node is reproduced)."""
    rho = np.hypot(d[:, 0], d[:, 1])
    ok = rho > 0
    safe = np.where(ok, rho, 1.0)
    c, s = d[:, 0] / safe, d[:, 1] / safe
    e_q = _edge(np.sin(np.radians(theta_q_deg)), c, s)
    e_k = _edge(np.sin(np.radians(theta_k_deg)), c, s)
    u = np.clip(rho / np.maximum(e_q, 1e-12), 0.0, 1.0)
    rho_k = rho + (e_k - e_q) * u**2
    scale = np.where(ok, rho_k / safe, 1.0)
    return d * scale[:, None]


def _bracket(axis, q, periodic=False):
    """(j0, j1, t) with q between axis[j0] and axis[j1] (edges held, or periodic over 360 deg)."""
    n = len(axis)
    if n == 1:
        z = np.zeros(q.shape, int)
        return z, z, np.zeros(q.shape)
    if periodic:
        span = 360.0
        q = axis[0] + np.mod(q - axis[0], span)
        ext = np.append(axis, axis[0] + span)
        j = np.clip(np.searchsorted(ext, q, side="right") - 1, 0, n - 1)
        t = (q - ext[j]) / (ext[j + 1] - ext[j])
        return j, (j + 1) % n, t
    qc = np.clip(q, axis[0], axis[-1])
    j = np.clip(np.searchsorted(axis, qc, side="right") - 1, 0, n - 2)
    t = (qc - axis[j]) / (axis[j + 1] - axis[j])
    return j, j + 1, t


@register("bsdf_table")
@dataclass(frozen=True, eq=False)
class BsdfTable:
    """Measured BSDF nodes per (sample rotation, incidence), interpolated in beta - beta0."""

    theta_i_deg: tuple
    blocks: tuple
    rotation_deg: tuple = (0.0,)
    scatter: str = "brdf"
    symmetry: str = "plane"
    tis: Optional[tuple] = None

    flags = ComponentFlags.GLOSSY
    reciprocal = False

    def __post_init__(self):
        if self.scatter not in ("brdf", "btdf"):
            raise MaterialError(f"{_OWNER}: 'scatter' must be 'brdf' or 'btdf', got {self.scatter!r}")
        if self.symmetry not in ("plane", "none"):
            raise MaterialError(f"{_OWNER}: 'symmetry' must be 'plane' or 'none', got {self.symmetry!r}")
        ti = _list("theta_i_deg", self.theta_i_deg, 0.0, 89.999999)
        rot = _list("rotation_deg", self.rotation_deg, -360.0, 720.0)
        if rot[-1] - rot[0] >= 360.0:  # a closing duplicate (0 ... 360): the periodic grid drops it
            keep = rot < rot[0] + 360.0 - 1e-9
            if not np.all(keep[: np.count_nonzero(keep)]):
                raise MaterialError(f"{_OWNER}: 'rotation_deg' spans more than 360 deg")
        if not isinstance(self.blocks, (list, tuple)) or len(self.blocks) != len(ti) * len(rot):
            raise MaterialError(
                f"{_OWNER}: 'blocks' must be a list of {len(rot)} x {len(ti)} = {len(ti) * len(rot)} "
                "blocks (rotation-major)")
        blocks = []
        for k, b in enumerate(self.blocks):
            where = f"{_OWNER}: blocks[{k}]"
            if not isinstance(b, dict) or set(b) != {"theta_r_deg", "phi_r_deg", "bsdf_per_sr"}:
                raise MaterialError(f"{where}: needs exactly the keys theta_r_deg, phi_r_deg, bsdf_per_sr")
            try:
                cols = [np.asarray(b[key], float) for key in ("theta_r_deg", "phi_r_deg", "bsdf_per_sr")]
            except (TypeError, ValueError):
                raise MaterialError(f"{where}: values must be lists of numbers") from None
            n = len(cols[0])
            if n < 1 or any(c.ndim != 1 or len(c) != n for c in cols):
                raise MaterialError(f"{where}: theta_r_deg, phi_r_deg, bsdf_per_sr must be lists of one length >= 1")
            if not all(np.all(np.isfinite(c)) for c in cols):
                raise MaterialError(f"{where}: values must be finite")
            if np.any(cols[0] < 0) or np.any(cols[0] >= 90):
                raise MaterialError(f"{where}: theta_r_deg must lie in [0, 90)")
            if np.any(cols[2] < 0):
                raise MaterialError(f"{where}: bsdf_per_sr must be >= 0")
            blocks.append({"theta_r_deg": tuple(map(float, cols[0])), "phi_r_deg": tuple(map(float, cols[1])),
                           "bsdf_per_sr": tuple(map(float, cols[2]))})
        object.__setattr__(self, "theta_i_deg", tuple(map(float, ti)))
        object.__setattr__(self, "rotation_deg", tuple(map(float, rot)))
        object.__setattr__(self, "blocks", tuple(blocks))
        if self.tis is not None:
            try:
                tis = tuple(None if v is None else float(v) for v in self.tis)
            except (TypeError, ValueError):
                raise MaterialError(f"{_OWNER}: 'tis' must be a list of numbers (null for a block without one)") from None
            object.__setattr__(self, "tis", tis)

    # ------------------------------------------------------------ interpolation

    @property
    def anisotropic(self) -> bool:
        return len(self._rotations) > 1

    @cached_property
    def _rotations(self):
        rot = np.asarray(self.rotation_deg)
        keep = rot < rot[0] + 360.0 - 1e-9
        return rot[keep]

    @cached_property
    def _blocks(self):
        nt = len(self.theta_i_deg)
        out = []
        for r in range(len(self._rotations)):
            row = []
            for j, ti in enumerate(self.theta_i_deg):
                b = self.blocks[r * nt + j]
                row.append(_Block(np.deg2rad(ti), np.deg2rad(b["theta_r_deg"]), np.deg2rad(b["phi_r_deg"]),
                                  b["bsdf_per_sr"], self.symmetry == "plane"))
            out.append(row)
        return out

    def table_value(self, rotation_deg, theta_i_deg, d):
        """Interpolated BSDF at sample rotations, specular angles (deg) and offsets d (n, 2)."""
        rotation_deg = np.broadcast_to(np.asarray(rotation_deg, float), (len(d),))
        theta_i_deg = np.broadcast_to(np.asarray(theta_i_deg, float), (len(d),))
        r0, r1, tr = _bracket(self._rotations, rotation_deg, periodic=True)
        i0, i1, ti = _bracket(np.asarray(self.theta_i_deg), theta_i_deg)
        lin = np.zeros(len(d))
        logs = np.zeros(len(d))
        positive = np.ones(len(d), bool)
        nodes = np.asarray(self.theta_i_deg)
        for rr, wr in ((r0, 1.0 - tr), (r1, tr)):
            for ii, wi in ((i0, 1.0 - ti), (i1, ti)):
                w = wr * wi
                for r in np.unique(rr):
                    for i in np.unique(ii):
                        m = (rr == r) & (ii == i) & (w > 0)
                        if np.any(m):
                            v = self._blocks[r][i](_to_block(d[m], theta_i_deg[m], nodes[i]))
                            lin[m] += w[m] * v
                            positive[m] &= v > 0
                            logs[m] += w[m] * np.log(np.where(v > 0, v, 1.0))
        # geometric blend where every contributing value is positive (BSDFs change by decades with
        # incidence near grazing); it never exceeds the linear blend, so energy stays bounded
        return np.where(positive, np.exp(logs), lin)

    def _local(self, wi, wo):
        """(rotation_deg, theta_i_deg, d) of each pair: d in the frame of its plane of incidence."""
        wi = np.asarray(wi, float)
        wo = np.asarray(wo, float)
        sin_i = np.hypot(wi[:, 0], wi[:, 1])
        phi_s = np.where(sin_i > 1e-12, np.arctan2(-wi[:, 1], -wi[:, 0]), 0.0)
        c, s = np.cos(phi_s), np.sin(phi_s)
        bx = c * wo[:, 0] + s * wo[:, 1]
        by = -s * wo[:, 0] + c * wo[:, 1]
        theta_i_deg = np.degrees(np.arctan2(sin_i, wi[:, 2]))
        d = np.stack([bx - sin_i, by], axis=-1)
        rotation = np.degrees(phi_s) - 90.0 - getattr(self, "_frame_offset_deg", 0.0)
        return rotation, theta_i_deg, d

    def oriented(self, offset_deg: float) -> "BsdfTable":
        """This table on a part whose sample x axis lies at azimuth ``offset_deg`` in the tracer's
        local frame (straylight.engine.spec.orient_materials); the material file is unchanged."""

        out = copy.copy(self)  # shares the built interpolants
        object.__setattr__(out, "_frame_offset_deg", float(offset_deg))
        return out

    def brdf(self, wi, wo, polarization: str = "u") -> np.ndarray:
        """Interpolated BSDF in 1/sr (no cos), (n,). For ``btdf`` tables wo is the transmitted
        direction mirrored through the surface (so hemisphere integrals give the transmittance)."""
        check_polarization(polarization)
        wi = np.asarray(wi, float)
        wo = np.asarray(wo, float)
        above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        out = np.zeros(len(wi))
        if np.any(above):
            rot, th, d = self._local(wi[above], wo[above])
            out[above] = self.table_value(rot, th, d)
        return out

    # ------------------------------------------------------------ energy

    def check_nodes_deg(self) -> np.ndarray:
        """Incidences the energy check adds to its 1-deg grid: the nodes and the midpoints between them."""
        ti = np.asarray(self.theta_i_deg)
        return np.unique(np.concatenate([ti, 0.5 * (ti[1:] + ti[:-1])]))

    def check_energy_table(self, where: str) -> None:
        """Refuse (MaterialError naming the incidence) a table whose reflectance reaches 1 at any
        sample rotation, at its incidence nodes or between them (midpoints and the 1-deg grid)."""
        # the nodes, midpoints and quarter points at every rotation; the 1-deg grid (Material.check_energy)
        # as well when the table has one rotation (values between nodes blend the two nodes' linearly)
        ti = np.asarray(self.theta_i_deg)
        quarter = np.concatenate([ti[:-1] + f * np.diff(ti) for f in (0.25, 0.5, 0.75)]) if len(ti) > 1 else ti
        grid = np.unique(np.concatenate([ti, quarter] + ([] if self.anisotropic else [np.arange(0.0, 90.0, 1.0)])))
        kind = "transmittance" if self.scatter == "btdf" else "reflectance"
        for r in self._rotations:
            rho = self.dhr(grid, r, 24, 36)
            near = (rho > 0.8) & (rho < 1.25)
            if np.any(near):
                rho[near] = self.dhr(grid[near], r, 48, 96)
            k = int(np.argmax(rho))
            if rho[k] >= 1.0:
                node = " (a node of the file)" if grid[k] in self.theta_i_deg else " (between the file's nodes)"
                rot = f", sample rotation {r:g} deg" if self.anisotropic else ""
                tis = ""
                if self.tis and grid[k] in self.theta_i_deg and len(self.tis) == len(self.blocks):
                    j = list(self._rotations).index(r) * len(self.theta_i_deg) + self.theta_i_deg.index(grid[k])
                    tis = f"; the file's TIS line says {self.tis[j]:g}" if self.tis[j] is not None else ""
                raise MaterialError(
                    f"{where}: not physical: directional-hemispherical {kind} {rho[k]:.4f} > 1 at incidence "
                    f"{grid[k]:g} deg{node}{rot}{tis}; refused (values are never rescaled)")

    def dhr(self, theta_i_deg, rotation_deg=0.0, n_radial=96, n_azimuth=192) -> np.ndarray:
        """Directional-hemispherical reflectance (transmittance for btdf) at sample rotation
        ``rotation_deg``: the quadrature of materials.albedo on this table alone."""

        return directional_hemispherical_reflectance(_Rotated(self, rotation_deg), np.radians(theta_i_deg), "u",
                                                     n_radial, n_azimuth)

    # ------------------------------------------------------------ sampling

    @cached_property
    def proposal_width(self) -> float:
        """Narrowest half-width at half maximum over the blocks, in beta (clipped to [1e-3, 1])."""
        widths = []
        for row in self._blocks:
            for b in row:
                if b.v.max() <= 0:
                    continue
                r = np.hypot(b.d[:, 0], b.d[:, 1])
                above = r[b.v >= 0.5 * b.v.max()]
                widths.append(max(float(above.max()), 0.0) if above.size else 1.0)
        if not widths:
            return 1.0
        return float(np.clip(min(widths), 1e-3, 1.0))

    def sample_direction(self, wi, u) -> np.ndarray:
        wi = np.asarray(wi, float)
        u2 = direction_uniforms(u)
        cos_half = u2[:, 0] < 0.5
        v = u2.copy()
        v[:, 0] = np.where(cos_half, 2.0 * u2[:, 0], 2.0 * u2[:, 0] - 1.0)
        wo = lobe_direction(wi, v, self.proposal_width, 2.0)
        if np.any(cos_half):
            wo[cos_half] = sample_cosine_hemisphere(v[cos_half])
        return wo

    def sample(self, wi, u, polarization: str = "u") -> Sample:
        check_polarization(polarization)
        wi = np.asarray(wi, float)
        wo = self.sample_direction(wi, u)
        pdf = self.pdf(wi, wo, polarization)
        above = (wo[:, 2] > 0) & (pdf > 0)
        f = self.brdf(wi, wo, polarization)
        weight = np.where(above, f * wo[:, 2] / np.where(above, pdf, 1.0), 0.0)
        return Sample(wo=wo, weight=weight, pdf_per_sr=np.where(above, pdf, 0.0))

    def pdf(self, wi, wo, polarization: str = "u") -> np.ndarray:
        wi = np.asarray(wi, float)
        wo = np.asarray(wo, float)
        cos_part = np.where(wi[:, 2] > 0, cosine_hemisphere_pdf(wo[:, 2]), 0.0)
        return 0.5 * cos_part + 0.5 * lobe_pdf(wi, wo, self.proposal_width, 2.0)

    @classmethod
    def example(cls) -> "BsdfTable":
        """A small plane-symmetric table for the component contract test: a Lambertian rd = 0.03
        plus a mild forward lobe, at incidences 0, 30, 60 and 80 deg."""
        theta_r = [float(a) for a in range(0, 90, 5)]
        phi_r = [float(a) for a in range(0, 181, 30)]
        blocks = []
        for ti in (0.0, 30.0, 60.0, 80.0):
            tr, pr, f = [], [], []
            for a in theta_r:
                for b in phi_r:
                    # cosine of the angle to the specular direction (theta_r = theta_i, phi_r = 0)
                    cs = (np.cos(np.radians(a)) * np.cos(np.radians(ti))
                          + np.sin(np.radians(a)) * np.sin(np.radians(ti)) * np.cos(np.radians(b)))
                    tr.append(a)
                    pr.append(b)
                    f.append(0.03 / np.pi + 0.01 * max(float(cs), 0.0) ** 8)
            blocks.append({"theta_r_deg": tr, "phi_r_deg": pr, "bsdf_per_sr": f})
        return cls(theta_i_deg=(0.0, 30.0, 60.0, 80.0), blocks=tuple(blocks))

    def to_dict(self) -> dict:
        out = {"type": "bsdf_table", "scatter": self.scatter, "symmetry": self.symmetry,
               "rotation_deg": list(self.rotation_deg), "theta_i_deg": list(self.theta_i_deg),
               "blocks": [{k: list(v) for k, v in b.items()} for b in self.blocks]}
        if self.tis is not None:
            out["tis"] = list(self.tis)
        return out


class _Rotated:
    """A table seen with its sample turned so that the incidence frame meets ``rotation_deg``."""

    def __init__(self, table, rotation_deg):
        self.table = table
        a = np.radians(rotation_deg + 90.0)
        self.c, self.s = np.cos(a), np.sin(a)

    def _turn(self, w):
        w = np.asarray(w, float)
        return np.stack([self.c * w[:, 0] - self.s * w[:, 1], self.s * w[:, 0] + self.c * w[:, 1], w[:, 2]], axis=-1)

    def brdf(self, wi, wo, polarization="u"):
        return self.table.brdf(self._turn(wi), self._turn(wo), polarization)


def rotated(model, rotation_deg):
    """``model`` seen at sample rotation ``rotation_deg`` (wi, wo given in the incidence frame)."""
    return _Rotated(model, rotation_deg)
