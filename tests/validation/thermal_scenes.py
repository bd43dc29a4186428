"""Scene files for the thermal checks: written to a temporary directory."""
from pathlib import Path

import numpy as np
import trimesh

MATERIALS = """
[material.black]
components = [{type = "lambertian", rd = 0.05}]
[material.grey]
components = [{type = "lambertian", rd = 0.5}]
[material.glossy]
wavelength_nm = 10000.0
components = [{type = "lambertian", rd = 0.2}, {type = "k_correlation", sigma_nm = 300.0, lc_um = 20.0, s = 2.5, r = 0.5}]
[material.mirror]
components = [{type = "specular", r = 0.9}]
"""


def write_box(directory, side_mm=100.0, n=4):
    """Six square walls of a closed box, each its own STL, normals pointing *into* the box (so the
    inside emits, CONTRACTS §7); returns {name: file name}."""
    directory = Path(directory)
    L = side_mm
    walls = {  # origin, u, v with v x u pointing inward
        "floor": ((0, 0, 0), (0, L, 0), (L, 0, 0)), "ceiling": ((0, 0, L), (L, 0, 0), (0, L, 0)),
        "wx0": ((0, 0, 0), (0, 0, L), (0, L, 0)), "wx1": ((L, 0, 0), (0, L, 0), (0, 0, L)),
        "wy0": ((0, 0, 0), (L, 0, 0), (0, 0, L)), "wy1": ((0, L, 0), (0, 0, L), (L, 0, 0)),
    }
    out = {}
    for name, (o, u, v) in walls.items():
        o, u, v = (np.asarray(x, float) for x in (o, u, v))
        verts = [o + u * i / n + v * j / n for i in range(n + 1) for j in range(n + 1)]
        faces = []
        for i in range(n):
            for j in range(n):
                a, b, c, d = i * (n + 1) + j, (i + 1) * (n + 1) + j, (i + 1) * (n + 1) + j + 1, i * (n + 1) + j + 1
                faces += [(c, b, a), (d, c, a)]
        trimesh.Trimesh(np.array(verts), np.array(faces), process=False).export(directory / f"{name}.stl")
        out[name] = f"{name}.stl"
    return out


def part(name, material=None, temperature_k=None, role=None, mesh=None, surface=None):
    lines = ["[[part]]", f'name = "{name}"']
    if mesh:
        lines.append(f'mesh = "{mesh}"')
    if surface:
        lines.append(f"surface = {surface}")
    if material:
        lines.append(f'material = "{material}"')
    if role:
        lines.append(f'role = "{role}"')
    if temperature_k is not None:
        lines.append(f"temperature_k = {float(temperature_k)}")
    return "\n".join(lines) + "\n"


def plane(center, axis, outer, inner=0.0):
    c = ", ".join(f"{float(x)}" for x in center)
    a = ", ".join(f"{float(x)}" for x in axis)
    s = f'{{type = "plane", vertex_mm = [{c}], axis = [{a}], outer_radius_mm = {float(outer)}'
    return s + (f", inner_radius_mm = {float(inner)}}}" if inner else "}")


def write_scene(directory, text, name="scene.toml"):
    path = Path(directory) / name
    path.write_text(MATERIALS + text)
    return path


def view_factor_coaxial_disks(r1, r2, h):
    """PHYSICS §5: disk r1 -> parallel coaxial disk r2 at distance h."""
    R1, R2 = r1 / h, r2 / h
    X = 1 + (1 + R2 ** 2) / R1 ** 2
    return (X - np.sqrt(X ** 2 - 4 * (R2 / R1) ** 2)) / 2


def write_tube_inward(directory, radius_mm, length_mm, name="wall.stl", n_phi=256, n_z=8):
    """Open cylinder wall r = radius, 0 <= z <= length, as triangles whose normals point to the axis
    (its inside emits, CONTRACTS §7)."""
    phi = np.linspace(0, 2 * np.pi, n_phi, endpoint=False)
    zs = np.linspace(0, length_mm, n_z + 1)
    verts = np.array([(radius_mm * np.cos(p), radius_mm * np.sin(p), z) for z in zs for p in phi])
    faces = []
    for k in range(n_z):
        for i in range(n_phi):
            j = (i + 1) % n_phi
            a, b, c, d = k * n_phi + i, k * n_phi + j, (k + 1) * n_phi + j, (k + 1) * n_phi + i
            faces += [(a, c, b), (a, d, c)]
    mesh = trimesh.Trimesh(verts, np.array(faces), process=False)
    assert (np.einsum("ij,ij->i", mesh.face_normals, mesh.triangles_center * [1, 1, 0]) < 0).all()
    mesh.export(Path(directory) / name)
    return name


def write_disk(directory, name, radius_mm, z_mm, normal_sign=1.0, n_phi=256):
    """A disk sheet (triangle fan) at height z, normals along +z (or -z with ``normal_sign`` -1)."""
    phi = np.linspace(0, 2 * np.pi, n_phi, endpoint=False)
    verts = np.vstack([[0.0, 0.0, z_mm], np.column_stack([radius_mm * np.cos(phi), radius_mm * np.sin(phi),
                                                          np.full(n_phi, z_mm)])])
    i = np.arange(n_phi)
    faces = np.column_stack([np.zeros(n_phi, int), 1 + i, 1 + (i + 1) % n_phi])
    if normal_sign < 0:
        faces = faces[:, ::-1]
    trimesh.Trimesh(verts, faces, process=False).export(Path(directory) / f"{name}.stl")
    return f"{name}.stl"
