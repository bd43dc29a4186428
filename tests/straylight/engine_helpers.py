"""Small scenes and a Lambertian stand-in for the engine tests (built from numpy / trimesh)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from geometry.analytic import Plane, analytic_part
from geometry.mesh import Part, Scene
from materials import load_material
from materials.base import Sample
from straylight.sources import CollimatedDisk


def assert_agrees_with_analog(res, analog, detector: str = "det", ledger: bool = True) -> None:
    """``res`` (a TraceResult) puts on ``detector`` the power the analog walk ``analog`` does, within 4 combined
    standard errors, both positive; with ``ledger`` its power ledger closes to 1e-9 of the emitted power."""
    b, a = res.detectors[detector], analog.detectors[detector]
    assert b.power_w > 0 and a.power_w > 0, (b, a)
    assert abs(b.power_w - a.power_w) <= 4 * math.hypot(b.stderr_w, a.stderr_w), (b, a)
    if ledger:
        assert abs(res.ledger["balance_residual_w"]) < 1e-9 * res.emitted_w


@dataclass(frozen=True)
class StandInLambertian:
    """f = rd / pi, cosine sampling with weight rd (test-only stand-in for materials.lambertian)."""

    rd: float

    def brdf(self, wi, wo, polarization="u"):
        return np.where((wi[:, 2] > 0) & (wo[:, 2] > 0), self.rd / np.pi, 0.0)

    def sample(self, wi, u, polarization="u"):
        r = np.sqrt(u[:, 1])
        phi = 2 * np.pi * u[:, 2]
        wo = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(0, 1 - r * r))], axis=-1)
        ok = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        return Sample(wo, np.where(ok, self.rd, 0.0), np.where(ok, wo[:, 2] / np.pi, 0.0))

    def pdf(self, wi, wo, polarization="u"):
        return np.where(wi[:, 2] > 0, np.maximum(wo[:, 2], 0) / np.pi, 0.0)



def quad_part(name, p0, e1, e2, material=None, role="surface", n=6):
    """A flat n x n-cell quad from corner p0 along e1 and e2 (its normal e1 x e2)."""
    s, t = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="ij")
    v = np.asarray(p0, float) + s.reshape(-1, 1) * np.asarray(e1, float) + t.reshape(-1, 1) * np.asarray(e2, float)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    f = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return Part(name, v, f, material=material, role=role)

def disk_part(name, z, radius, n_seg=512, role="detector", material=None, facing=+1, circumscribe=False):
    """Flat N-gon disk in the plane z (normal +z if facing > 0)."""
    R = radius / np.cos(np.pi / n_seg) if circumscribe else radius
    a = np.linspace(0, 2 * np.pi, n_seg, endpoint=False)
    v = np.vstack([[0, 0, z], np.stack([R * np.cos(a), R * np.sin(a), np.full(n_seg, z)], axis=1)])
    i = np.arange(n_seg)
    f = np.stack([np.zeros(n_seg, int), 1 + i, 1 + (i + 1) % n_seg], axis=1)
    if facing < 0:
        f = f[:, ::-1]
    return Part(name, v, f, material=material, role=role)


def annulus_part(name, z, r_in, r_out, n_seg=256, role="surface", material=None, facing=+1):
    a = np.linspace(0, 2 * np.pi, n_seg, endpoint=False)
    inner = np.stack([r_in * np.cos(a), r_in * np.sin(a), np.full(n_seg, z)], axis=1)
    outer = np.stack([r_out * np.cos(a), r_out * np.sin(a), np.full(n_seg, z)], axis=1)
    v = np.vstack([inner, outer])
    i = np.arange(n_seg)
    j = (i + 1) % n_seg
    f = np.concatenate([np.stack([i, n_seg + i, n_seg + j], 1), np.stack([i, n_seg + j, j], 1)])
    if facing < 0:
        f = f[:, ::-1]
    return Part(name, v, f, material=material, role=role)


def cylinder_wall_part(name, radius, z0, z1, n_seg=512, role="detector", material=None, inward=True,
                       circumscribe=True):
    """Open cylinder (N-gon prism side), normals inward by default."""
    R = radius / np.cos(np.pi / n_seg) if circumscribe else radius
    a = np.linspace(0, 2 * np.pi, n_seg, endpoint=False)
    lo = np.stack([R * np.cos(a), R * np.sin(a), np.full(n_seg, z0)], axis=1)
    hi = np.stack([R * np.cos(a), R * np.sin(a), np.full(n_seg, z1)], axis=1)
    v = np.vstack([lo, hi])
    i = np.arange(n_seg)
    j = (i + 1) % n_seg
    f = np.concatenate([np.stack([i, j, n_seg + j], 1), np.stack([i, n_seg + j, n_seg + i], 1)])
    if inward:
        f = f[:, ::-1]
    return Part(name, v, f, material=material, role=role)


def merge_parts(name, parts, role, material=None):
    verts, faces, off = [], [], 0
    for p in parts:
        verts.append(p.vertices_mm)
        faces.append(p.faces + off)
        off += len(p.vertices_mm)
    return Part(name, np.vstack(verts), np.vstack(faces), material=material, role=role)


def baffled_tube_scene(material="black"):
    """The reference baffled tube of BENCHMARK.md from annuli and cylinders (mm)."""
    n = 256
    wall = [cylinder_wall_part("w_in", 50, 0, 300, n, "surface", inward=True, circumscribe=False),
            cylinder_wall_part("w_out", 51, -1, 300, n, "surface", inward=False, circumscribe=False),
            annulus_part("rim", 300, 50, 51, n, "surface")]
    vanes = []
    for zc in range(40, 281, 40):
        vanes += [annulus_part("vt", zc + 0.5, 35, 50, n, "surface"),
                  annulus_part("vb", zc - 0.5, 35, 50, n, "surface", facing=-1),
                  cylinder_wall_part("vi", 35, zc - 0.5, zc + 0.5, n, "surface", inward=True, circumscribe=False)]
    plate = [annulus_part("pt", 0, 35, 50, n, "surface"), annulus_part("pb", -1, 35, 51, n, "surface", facing=-1),
             cylinder_wall_part("pi", 35, -1, 0, n, "surface", inward=True, circumscribe=False)]
    parts = (
        merge_parts("wall", wall, "surface", material),
        merge_parts("vanes", vanes, "surface", material),
        merge_parts("end_plate", plate, "surface", material),
        disk_part("detector", 0.0, 35.0, n, "detector"),
    )
    return Scene(parts)


def icosphere_ports_scene(radius_mm, port_fractions, subdivisions=5, material="wall"):
    """Sphere (outward normals) split into wall and ports: {name: (axis, area fraction, role)}.

    Triangles whose centroid lies within a cap are given to that port; role None = a hole.
    Returns (scene, actual area fractions).
    """
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius_mm)
    tri = m.vertices[m.faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    cen = tri.mean(axis=1)
    cen /= np.linalg.norm(cen, axis=1, keepdims=True)
    owner = np.full(len(tri), -1)
    fractions = {}
    parts = []
    for k, (name, (axis, frac, role)) in enumerate(port_fractions.items()):
        axis = np.asarray(axis, float) / np.linalg.norm(axis)
        cos_cap = 1 - 2 * frac  # cap area fraction (1 - cos a) / 2
        sel = (cen @ axis >= cos_cap) & (owner < 0)
        owner[sel] = k
        fractions[name] = area[sel].sum() / area.sum()
        if role is not None:
            parts.append(Part(name, m.vertices, m.faces[sel], role=role))
    wall = owner < 0
    parts.insert(0, Part("wall", m.vertices, m.faces[wall], material=material, role="surface"))
    return Scene(tuple(parts)), fractions


def window_scene(face_radius_mm: float = 100.0, source_z_mm: float = 60.0, source_radius_mm: float = 5.0):
    """An uncoated glass window (n = 1.5, analytic faces "top" at z = 10 and "bottom" at z = 0, radius
    ``face_radius_mm``) over a detector disk "det" at z = -20, lit at normal incidence by a collimated beam from
    z = ``source_z_mm``: (scene, source, materials). By default (a 5 mm beam on 100 mm faces): nominal image
    (1 - R)^2, two-bounce ghost (1 - R)^2 R^2 with R = 0.04."""
    up = np.array([0.0, 0.0, 1.0])
    glass = load_material({"name": "glass", "components": [{"type": "dielectric", "n": 1.5}]})
    top = analytic_part("top", Plane(np.array([0, 0, 10.0]), up, math.inf, 0.0, face_radius_mm, 0.0), "glass")
    bottom = analytic_part("bottom", Plane(np.zeros(3), -up, math.inf, 0.0, face_radius_mm, 0.0), "glass")
    det = analytic_part("det", Plane(np.array([0, 0, -20.0]), up, math.inf, 0.0, 300.0, 0.0), None, "detector")
    src = CollimatedDisk(center_mm=np.array([0, 0, source_z_mm]), normal=-up, direction=-up,
                         radius_mm=source_radius_mm)
    return Scene((top, bottom, det)), src, {"glass": glass}
