"""The detectors' field through the lens, as a cone of directions: where the trees' end draws aim a share of
their draws (straylight.engine.tree_ends, "Draws into the field").

A scatter point P seen through a lens ("P -> front (T) -> back (T) -> sensor": the guide scope's lens-cell lip,
lit by the back face's reflection) reaches a sensor at the lens's focus only along the directions the lens
images onto it: the object-side field, a cone of half-angle ~ atan(r_sensor / f) about the axis whatever P's
place (0.86 deg on the guide scope). A draw from P's glossy lobe lands there rarely (30 deg, seed 6: 6 of 2.6e5
end draws at the lens cell scored). The cone is measured, not assumed: :data:`FIELD_RAYS` rays from uniform points on the
detectors toward uniform points on the analytic interfaces (an own stream), refracted through them (:func:`exit_directions`);
the directions back along those that leave the glass into the air (P's outgoing direction toward the detector)
give the axis (their mean) and the half-angle (the largest angle from it, times :data:`FIELD_MARGIN`). No cone
(None) with fewer than :data:`FIELD_MIN_RAYS` such rays or a half-angle above :data:`FIELD_MAX_DEG` (a wide
field: the lobe covers it itself), or without an analytic interface."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from straylight.engine.triangle_sampling import triangle_areas, triangle_points

#: rays traced from the detectors to measure the field (a few ms on the guide scope)
FIELD_RAYS = 8192
#: rays out of the lens needed for a cone
FIELD_MIN_RAYS = 64
#: a field wider than this is left to the lobe draw alone
FIELD_MAX_DEG = 10.0
#: the half-angle: the rays' largest angle from the axis times this (they are a sample of the field)
FIELD_MARGIN = 1.25
#: the second entropy word of the field's own stream (after the seed)
FIELD_STREAM = 0x4649454C  # "FIEL"


@dataclass(frozen=True)
class FieldCone:
    """Directions within ``half_angle_deg`` of the unit ``axis``; drawn uniformly in solid angle."""

    axis: tuple
    half_angle_deg: float

    @property
    def cos_half(self) -> float:
        return math.cos(math.radians(self.half_angle_deg))

    @property
    def density_per_sr(self) -> float:
        """The uniform draw's density within the cone, 1 / (2 pi (1 - cos half-angle))."""
        return 1.0 / (2.0 * math.pi * (1.0 - self.cos_half))

    def contains(self, d: np.ndarray) -> np.ndarray:
        """(n,) bool: the unit directions ``d`` (n, 3) within the cone."""
        return np.asarray(d, dtype=np.float64) @ np.asarray(self.axis, dtype=np.float64) >= self.cos_half

    def sample(self, u: np.ndarray) -> np.ndarray:
        """(n, 3) unit directions uniform in the cone from uniforms ``u`` (n, 2): cos theta uniform on
        [cos half, 1], phi uniform."""
        u = np.asarray(u, dtype=np.float64)
        cos_t = 1.0 - u[:, 0] * (1.0 - self.cos_half)
        sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t * cos_t))
        phi = 2.0 * math.pi * u[:, 1]
        a = np.asarray(self.axis, dtype=np.float64)
        t1 = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        t1 /= np.linalg.norm(t1)
        t2 = np.cross(a, t1)
        return (cos_t[:, None] * a + (sin_t * np.cos(phi))[:, None] * t1 + (sin_t * np.sin(phi))[:, None] * t2)


@dataclass(frozen=True)
class FieldTable:
    """The delta-chain strategy's table: the field ``cone`` of its end draws (None: none) and why not."""

    cone: FieldCone | None
    why_none: str = ""


def cone_of(omega: np.ndarray) -> FieldCone | None:
    """The cone of the unit directions ``omega`` (n, 3) (module doc), or None."""
    omega = np.asarray(omega, dtype=np.float64)
    if len(omega) < FIELD_MIN_RAYS:
        return None
    mean = omega.sum(axis=0)
    norm = float(np.linalg.norm(mean))
    if norm == 0.0:
        return None
    axis = mean / norm
    widest = math.degrees(math.acos(float(np.clip(np.min(omega @ axis), -1.0, 1.0))))
    half = FIELD_MARGIN * widest
    if not 0.0 < half <= FIELD_MAX_DEG:
        return None
    return FieldCone(tuple(float(x) for x in axis), half)


def build(spec, scene) -> FieldTable:
    """The field of ``spec``'s detectors through its analytic interfaces (module doc), traced on ``scene`` (the
    compiled scene of straylight.engine.runtime)."""
    omega = exit_directions(spec, scene)
    cone = cone_of(omega)
    if cone is None:
        return FieldTable(None, f"{len(omega)} of {FIELD_RAYS} rays from the detectors left the lens, not in a "
                                f"cone of <= {FIELD_MAX_DEG:g} deg")
    return FieldTable(cone)


def exit_directions(spec, scene) -> np.ndarray:
    """(m, 3): for :data:`FIELD_RAYS` rays from uniform points on the detectors toward uniform points on the
    analytic interfaces (own stream), refracted at every interface they meet (exact surfaces:
    straylight.engine.lens_vertex.transmit_step, as its find_runs traces the beam), the direction back along each that left the glass
    after one interface or more into the air (met a part that is not an interface, or nothing): P's outgoing
    direction toward the detector."""
    from straylight.engine.lens_vertex import interface_parts, transmit_step

    iface = interface_parts(spec)
    tri_ids = np.flatnonzero(iface[spec.triangle_part]) if iface.any() else np.zeros(0, np.int64)
    dets = scene.detectors
    if len(tri_ids) == 0 or not dets:
        return np.zeros((0, 3))
    rng = np.random.default_rng([int(spec.seed), FIELD_STREAM])
    n = FIELD_RAYS
    tri = np.asarray(spec.triangles_mm, dtype=np.float64)[tri_ids]
    area = triangle_areas(tri)
    k = rng.choice(len(tri_ids), n, p=area / area.sum())
    u1, u2 = rng.random(n), rng.random(n)
    target = triangle_points(tri, k, u1, u2)
    j = rng.integers(0, len(dets), n)
    z = np.empty((n, 3))
    for jj in range(len(dets)):
        g = np.flatnonzero(j == jj)
        z[g] = dets[jj].sample(rng.random((len(g), 3)))[0]
    d = target - z
    d /= np.linalg.norm(d, axis=1)[:, None]
    o = z + 2.0 * spec.eps * d
    crossed = np.zeros(n, dtype=np.int64)
    inside = np.zeros(n, dtype=bool)  # in glass
    last = np.full(n, -1)
    live = np.arange(n)
    out = []
    for _ in range(2 * max(int(spec.options.estimator.delta_chain), 1) + 2):
        if len(live) == 0:
            break
        part, again, through = transmit_step(spec, scene, iface, o, d, last, live)
        at_iface = (part >= 0) & ~again & iface[np.maximum(part, 0)]
        left = ~again & ~at_iface & (crossed[live] >= 1) & ~inside[live]  # out of the lens into the air
        out.append(-d[live[left]])
        nxt = [live[again]]
        for _p, i, front in through:
            inside[i] = front
            crossed[i] += 1
            nxt.append(i)
        live = np.concatenate(nxt)
    return np.concatenate(out) if out else np.zeros((0, 3))
