"""Reverse chains: what the detector sees through runs of interfaces, joined to the walk.

Behind a lens a scatter point P counts only if the light it sends through the glass lands on the
small sensor: the walk finds such a direction by chance (on the guide scope at 45-60 deg a few rays
in 1e5 carried 98 % of the variance, each a tube point whose two-reflection ghost crosses the sensor),
and next-event estimation cannot aim through a refracting surface. So the path is built from both
ends. Per ray of the walk M = :data:`EYES_PER_RAY` *eye chains* start on a detector: a point z uniform
on it (density 1 / A), a direction omega on its counted side (density q cos / pi: cosine-distributed
with q = 1, or drawn from the eye table below, whose q also carries the share of the chains its
detector and side get), cast and split at
every interface (parts whose kind declares ``Capability.DELTA_CHAIN``: reflection and transmission
both followed, as ``delta_chain`` does) for up to K interfaces. A branch that, after k >= 1
interfaces, meets a scatter part whose material is a non-polarizing pure scatterer ends there at an
*end point* P with the importance

    beta = pi A D (x 2 with both sides counted) x (v_P)_0 / (q M),

D the number of detectors and v the chain's Stokes covector: (1, 0, 0, 0) at the detector (it
measures power), carried back through each interface as v_in = M^T v_out (M the interface's Mueller
matrix for the forward light, in its s/p frame; frames turned by the inverse rotation) and
multiplied by the bulk transmission: (v_P)_0 is exactly the power the chain delivers for
unpolarized light leaving P, and a non-polarizing scatterer sends unpolarized light whatever it
receives (materials.polarized_brdf). Transmission coefficients are reciprocal (power-normalised
amplitudes), so the eye ray's Fresnel factors are the forward light's.

**The eye table** (:func:`build_table`, before the walk, like the entrance table): behind a lens the
chains that end on a scatter point the beam lights are few (on the guide scope 1 in 1300 cosine-drawn
chains at 60 deg, 1 in 900 at 30 deg, where the tube's glossy highlight seen through the ghost carries
70 % of the value in 5 of them). A pilot of :data:`PILOT_EYES` cosine-drawn chains (own streams) joined
to the source gives each chain's value x; per detector and side (a *key*), the direction's two
cosine-map uniforms (radius sqrt(u1), azimuth 2 pi u2) get the entrance table's density
(straylight.engine.entrance_sampling: proportional to the smoothed RMS of x at four scales, mixed at its
SCALE_WEIGHTS, a quarter left cosine), and the chains draw their directions from it. The keys themselves are drawn by the
pilot's value: P_key proportional to the root of the key's second moment E[x^2 / q_dir] under its
table (the variance-optimal split of the chains among strata), a share :data:`KEY_DEFENSIVE` spread
evenly over the keys (a key the pilot saw nothing on keeps it); the first uniform picks the key by
inverse CDF. With both sides counted the uniform choice spent half the chains on the detector's back,
which on the guide scope sees no light (the pilot joins none of its ~1e5 back chains at any angle): the
table now gives the front 0.95. q = (P_key D x sides) x the direction table's density, so beta and the
balance weights below take the key's share with the direction's; for a split tree's branch the eye
side's q is looked up from the direction it reaches the detector with
(:meth:`EyeTable.density_of_arrival`). Flat detectors only (the table is over one frame).
The pilot traces its first :data:`PILOT_FIRST_EYES` chains first (uniform keys): when none of them is
joined (near the axis the beam lights nothing the chains reach: the guide scope at 0 deg joins none of
2e5) it ends there without a table; otherwise the rest draws its keys by the first stage's key
probabilities (its directions still cosine), and each chain's x q (its value at a uniform key) goes to
its key's cells. Guide scope, 6 seeds at 1e5 rays (variance_paths.py, the same process), CPU s x rel^2
(%^2) median (mean), uniform keys -> keys by value: 30 deg 11.4 (14.2) -> 10.0 (11.8), 45 deg 26.5
(41.2) -> 25.0 (36.4), 60 deg 3.8 (4.1) -> 2.3 (2.9) (a second pair: 10.8 -> 9.2, 27.0 -> 24.2, 3.5 ->
2.1; 5 and 20 deg: the same relative errors, CPU +4-6 %); the front chains cost more than the back ones
(CPU +10-20 %). At 30-45 deg 70 % of the variance is the split trees' share of the ghost family (a
tube point's glossy draw whose tree lands on the sensor, ~1e-3 per ray: tree share 0.88-0.99, the eye
side's density 1/100 of the walk's there); the eye side's own pilot efficiency (mean^2 / mean of x^2,
~1e-3, one chain in 2e5 holding most of the sum of squares: the glossy peak) did not improve with the
rest's directions guided by the first stage (as entrance_sampling does: 18000 instead of 400 joined
chains at 45 deg, but 0.4 CPU s more and 30 deg 13.9 median), with 1024-cell grids, or with a table per
cell of a 2 x 2 to 8 x 8 grid of detector points (docs/engine.md, "Eye chains by detector and side").

Two connections count the paths "X -> P -> interfaces (1..K) -> detector":

- X the source (one ``collimated_disk``): P lit straight by the beam, irradiance E = Phi / (pi r^2
  |d . n_src|) x cos_P, unblocked to the source disk: ``beta f_P(-d, omega_P) E cos_P``;
- X a scatter vertex A of the walk whose scatter is non-polarizing (weight w, arriving from wi):
  ``w f_A(wi, A->P) cos_A cos_P / |AP|^2 f_P(P->A, omega_P) beta x n_ends`` for one of the ray's
  n_ends end points drawn uniformly, when A and P see each other.

Each ray's eye chains are its own (a stream keyed by seed and chunk), so the rays stay independent
and the engine's per-ray error stays right. The walk's own paths of that family are dropped (their
weight to the NEE exchange, the ledger stays exact), and so are delta_chain's split trees and
reflection_split's reflections that start after such a P (:meth:`ReverseChains.claims`): each path
is counted once. Paths with a pass-through (a hit outside a clear aperture) between X and P stay
the walk's (shadow rays do not pass apertures); passes inside the run are followed by both sides.

Contributions go to ``detector_nee`` and, negated, to the NEE-exchange row of P's part (source
connection) or A's part (vertex connection). Cost per ray: the eye chains (M x ~2-6 casts in a singlet)
and one shadow ray per end point and per eligible scatter vertex.

**Where the chains pay.** The eye pilot's chains are joined to the source, and each chain's value x
is an unbiased estimate of the power their family carries ("source -> P -> 1..K interfaces ->
detector", F = mean of x over the pilot's chains). The entrance pilot, built before it and without the
chains, estimates the power on the detectors (``TableTools.measured["detected_w"]``,
straylight.engine.strategies.entrance.PilotPower). When F is below :data:`EYE_SHARE_OFF` of that power
after the pilot's first stage or after all of it (:func:`verdict`), the vertex connections' main family is
weighed too: from each end point :data:`PILOT_SCATTER_DRAWS` cosine-drawn directions find the plain
scatter points A the beam lights, and "source -> A -> P -> interfaces" is added to F
(:func:`once_scattered`, :func:`_judge`; on the glass slab of test_reverse_chain.py it agrees with the
analog walk's records of that family, 2.16e-5 +- 0.04e-5 W against 2.09e-5 +- 0.27e-5 W). When the sum is
still below the share, the pilot ends there and returns
:class:`EyesOff`; the plan turns the strategy off and says why (``TraceResult.strategies``: "the eye
pilot's chains carried 0.00027 of the detected power ..."), and the walk counts the family itself, as
without the strategy: the estimate stays unbiased for any verdict (both pilots use their own streams).
Without the entrance pilot's power (entrance sampling off, or a pilot that saw no light) the chains run.
On the guide scope (pilots of seeds 1-10, F over the detected power; the first stage's in brackets):
0 deg 0 (none of the first 5e4 chains joined), 5 deg 1.1-1.7e-5, 10 deg 4.2-5.4e-5, 15 deg 1.3-2.0e-4,
20 deg 3.3-5.9e-4 (2.1-7.3e-4); 30 deg 0.35-0.87 (0.10-1.9), 45 deg 0.49-113 (0.079-2.6), 60 deg 0.28-1200
(the entrance pilot misses most of the ghost there): 5x below the limit at 20 deg, 25x above it at
30-60 deg. Traces of 6e4 rays (seed 1) with the chains on agree: their source connections carry 1.6e-5
(5 deg) to 4.4e-4 (20 deg) of the power and < 1e-6 of the variance, 0.40 / 0.54 / 0.99 at 30 / 45 / 60
deg (0.45 / 0.64 / 0.90 of the variance); their vertex connections (of any order)
carry < 1e-6 of the power at 5-20 deg and 1.5e-5 / 6.5e-6 / 2.3e-3 at 30 / 45 / 60 deg. Turning the
chains off at 5-20 deg leaves the estimate and its error as they were (0.97 %, 1.32 %, 1.25 % at 6e4 rays,
seed 1) and saves their cost: whole ``pst --target-rel-error 0.02`` commands (seeds 1 and 2, two rounds
alternated with the rule's absence, three rounds) 0.52-0.56 CPU s less at 5, 10 and 20 deg (11-12 % of ~4.7
CPU s), 0.08 less at 0 deg, the eye pilot ending after its first stage (docs/engine.md, "Where the eye chains pay"). A family left to the walk at the limit share adds at most ~0.3 % to the relative error even
with the walk's worst tail there (60 deg without the chains: 94 % at 6e4 rays). The once-scattered light
costs ~10 ms on the guide scope (~900 end points per 5e4 chains; 1e-14 to 1e-8 of the detected power at
0-20 deg, so it changes no verdict there). What the rule still cannot see: light scattered two or more
times before P, or reaching the end points through a pass-through; the walk then counts it alone, as
before the strategy.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import math

import numpy as np

from materials.flags import ComponentFlags, flags_of
from materials.mueller import apply_interface_mueller, rotate_stokes, s_vector
from materials.polarized_brdf import is_polarizing
from materials.smooth import reflect, refract
from materials.sampling import invert_cosine_hemisphere_sample, lazy_njit, sample_cosine_hemisphere
from straylight.engine.capabilities import Capability
from straylight.engine.delta_chain import CODE_COLUMNS, concat_codes, widen_codes
from straylight.engine.entrance_sampling import density as entrance_density
from straylight.engine.entrance_sampling import table_from_contributions, warp
from straylight.engine.interactions.registry import parts_with
from straylight.engine.interface_rows import deflected, frame_rotation, unit_s_vector
from straylight.engine.material_groups import by_material, distinct
from straylight.engine.surface_geometry import at_interfaces, branch_coefficients, cast_branches
from straylight.engine.ray_batch import EVENT_DETECTOR, EVENT_SCATTER, EVENT_SPECULAR
from straylight.engine.roles import ROLE_DETECTOR
from straylight.engine.walk_shares import keep_walk_share
from straylight.engine.vec3 import take_rows, tangent_frame
from straylight.paths import mix_key
from straylight.polarization import UNPOLARIZED
from straylight.rng import CHUNK_RAYS
from straylight.sources import CollimatedDisk, orthonormal_basis

STREAM = 0x52564348  # entropy word of the eye chains' streams ("RVCH")
#: eye chains per ray of the walk (the ray's eye estimate is their mean). A chain costs ~1.5 us, a ray of
#: the walk on the guide scope ~25 us; measured there (variance_paths.py, 3e5 rays, seeds 1-3, CPU s x
#: rel. error^2): 30 deg 56 / 16 / 30 with 1 chain, 22 / 16 / 35 with 2, 25 / 17 / 28 with 4; 60 deg
#: 8.5 / 55 / 8.2, 4.9 / 8.9 / 5.6, 7.7 / 7.1 / 27. With the keys by value (6 seeds at 1e5 rays, median, 2 -> 4
#: chains): 5 deg 6.3 -> 7.2, 20 deg 5.0 -> 5.5, 30 deg 8.5 -> 8.8, 45 deg 22.1 -> 19.8, 60 deg 2.06 -> 1.77
EYES_PER_RAY = 2
#: eye chains of the pilot that learns the direction table (:func:`build_table`)
PILOT_EYES = 200_000
#: its first stage: when none of these chains is joined to the source, the pilot ends without a table
PILOT_FIRST_EYES = 50_000
#: share of the eye chains spread evenly over the (detector, side) keys; the rest goes by the pilot's value
KEY_DEFENSIVE = 0.1
#: the chains run only where the eye pilot's estimate of their family's power (its source connections)
#: is at least this share of the entrance pilot's detected power (module doc, "Where the chains pay"):
#: guide scope, pilots of 10 seeds, 5-20 deg 1.1e-5 to 5.9e-4 (first stage up to 7.3e-4), 30-60 deg
#: 0.28 and more (first stage 0.079 and more); a family the walk is left with at this share adds at most
#: ~0.3 % to the relative error even with the walk's worst tail there (60 deg without chains: 94 %)
EYE_SHARE_OFF = 3e-3
#: directions drawn from each of the pilot's end points for the light the beam scatters once before it
#: (:func:`once_scattered`, only where the source connections alone say off): on the guide scope ~900 end
#: points per 5e4 chains, 2-3 ms of CPU with one draw each
PILOT_SCATTER_DRAWS = 8
#: the pilot's chunk streams start here (never reached by a trace's own chunks, nor the entrance pilot's)
PILOT_CHUNK_OFFSET = 1 << 41
_GOLDEN = 0.6180339887498949  # Weyl step of a ray's end-point choices over its depth


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


def unsupported(spec) -> str | None:
    """Why the strategy cannot run on ``spec`` (None when it can)."""
    if not parts_with(spec, Capability.DELTA_CHAIN).any():
        return "the scene has no interface for its chains to cross (no part whose kind declares DELTA_CHAIN)"
    if spec.options.estimator.target_parts:
        return "its balance weights use the materials' own pdf; target sampling draws from a mixture"
    if len(spec.sources) != 1 or not isinstance(spec.sources[0], CollimatedDisk):
        return "it joins its end points to exactly one collimated_disk source"
    if spec.options.physics.polarization != "u":
        return "its chains carry the polarization of unpolarized light; this trace fixes s or p"
    return None


def scatter_ends(spec) -> np.ndarray:
    """Bool per material (index into ``spec.materials``, plus a last False for 'none'): a pure
    scatterer that sends unpolarized light on when it receives unpolarized light, where an eye chain
    may end and a vertex connection may start. That is every pure scatterer under the default
    ``scatter_polarization = "auto"`` (the walk drops the polarization scatter creates from
    unpolarized light, straylight.engine.interactions.stokes), and the non-polarizing ones under "on"."""
    auto = spec.options.physics.scatter_polarization == "auto"
    out = []
    for m in spec.materials:
        flags = flags_of(m)
        out.append(not (flags & ComponentFlags.DELTA) and (auto or not is_polarizing(m)))
    return np.array(out + [False], dtype=bool)


def _source_linear(spec) -> bool:
    return bool(getattr(spec.sources[0], "polarization", UNPOLARIZED).is_linear)


def _local(v, n, frame=None) -> np.ndarray:
    """World directions ``v`` (m, 3) in the frames (t, b, n) of normals ``n`` (sources.orthonormal_basis;
    ``frame``: its (t, b) when already known)."""
    t, b = orthonormal_basis(n) if frame is None else frame
    return np.stack([_dot(v, t), _dot(v, b), _dot(v, n)], axis=1)


def beam_density(w0: float, weight_w, direction, normal, footprint: float) -> np.ndarray:
    """The walk's area density of its first vertices (P lit straight by the beam): the beam's footprint over the
    entrance density the start weight carries, w0 / w x |d . n_P| / footprint (rays of weight ``weight_w``
    arriving along ``direction`` at facing normals ``normal``; 0 where the weight is 0)."""
    w = np.asarray(weight_w, dtype=np.float64)
    return (w0 / np.where(w > 0, w, np.inf)) * np.abs(_dot(direction, normal)) / footprint


def _beam_footprint(src) -> float:
    """Area (mm^2) the collimated disk ``src`` covers across its beam: pi r^2 |d . n_src|."""
    return float(np.pi * src.radius_mm ** 2 * abs(float(np.dot(src.direction, src.normal))))


def _brdf(spec, mat, n, wi, wo, with_pdf=False):
    """Unpolarized BRDF of materials ``mat`` at frames of normals ``n`` (world directions wi toward
    the light, wo toward the viewer, both on the normal's side); with ``with_pdf`` also the
    material's sampling pdf of wo (the walk's draw there)."""
    frame = orthonormal_basis(n)  # one frame for both directions
    li, lo = _local(wi, n, frame), _local(wo, n, frame)
    f = np.zeros(len(mat))
    pdf = np.zeros(len(mat))
    pol = spec.options.physics.polarization
    for rows, (fv, pv) in by_material(spec.materials, mat, lambda model, rows: (
            model.brdf(li[rows], lo[rows], pol), model.pdf(li[rows], lo[rows], pol) if with_pdf else 0.0)):
        f[rows] = fv
        pdf[rows] = pv
    return (f, pdf) if with_pdf else f


def _entrance_density(spec, src, q) -> np.ndarray:
    """The entrance table's density factor at the beam points ``q`` (1 without a table)."""
    if spec.entrance_table is None:
        return np.ones(len(q))
    return entrance_density(spec.entrance_table, src.uniforms_at(q))


def source_connection(spec, scene, e):
    """The source connections of end points ``e`` (:class:`EyeEnds`): the indices ``g`` of the end
    points lit straight by the beam (unblocked), their value ``beta f_P(-d, omega_P) E cos_P`` (per
    eye chain, before the 1/N share and the balance weight), the walk's density of (P, omega_P) there
    (for the balance weight), the number of shadow rays cast and the walk's area density of P alone."""
    src = spec.sources[0]
    d = np.asarray(src.direction, float)
    cos_p = -(e.normal @ d)
    denom = float(d @ src.normal)
    none = np.zeros(0, np.int64), np.zeros(0), np.zeros(0), 0, np.zeros(0)
    if abs(denom) < 1e-12 or len(e.ray) == 0:
        return none
    t = ((e.point - src.center_mm) @ src.normal) / denom
    q = e.point - t[:, None] * d[None, :]
    inside = np.einsum("ij,ij->i", q - src.center_mm, q - src.center_mm) <= src.radius_mm ** 2
    g = np.flatnonzero((cos_p > 0) & (t > 2 * spec.eps) & inside)
    if len(g) == 0:
        return none
    origin = np.ascontiguousarray(e.point[g] + 2.0 * spec.eps * e.normal[g])
    dirs = np.ascontiguousarray(np.broadcast_to(-d, (len(g), 3)))
    blocked = np.asarray(scene.isect.occluded(origin, dirs, np.ascontiguousarray(t[g] - 4.0 * spec.eps)))
    shadows = len(g)
    g = g[~blocked]
    if len(g) == 0:
        return none[:3] + (shadows, none[4])
    footprint = _beam_footprint(src)
    wi = np.ascontiguousarray(np.broadcast_to(-d, (len(g), 3)))
    f, pdf = _brdf(spec, e.material[g], e.normal[g], wi, e.omega[g], with_pdf=True)
    p_area = _entrance_density(spec, src, q[g]) * cos_p[g] / footprint
    raw = e.beta[g] * f * (src.power_w / footprint) * cos_p[g]
    return g, raw, p_area * pdf, shadows, p_area


def eye_uniforms(spec, first_chunk: int, stop_chunk: int, n: int, chunk_offset: int, per_ray: int = 1) -> np.ndarray:
    """The uniforms (n x ``per_ray``, 7, ray-major) of the eye chains of the n rays of chunks
    ``first_chunk``..``stop_chunk`` (a stream per chunk, keyed by seed, ``chunk_offset`` + chunk and
    :data:`STREAM`): detector choice, detector point (3), direction (2), end-point choice."""
    m = int(per_ray)
    u = np.empty((n * m, 7))
    for c in range(first_chunk, stop_chunk):
        lo = (c - first_chunk) * CHUNK_RAYS
        hi = min(lo + CHUNK_RAYS, n)
        if hi <= lo:
            break
        rng = np.random.default_rng([int(spec.seed), int(chunk_offset + c), STREAM])
        rng.random(out=u[lo * m:hi * m])  # drawn in place: the same stream as rng.random(((hi - lo) * m, 7))
    return u


def _flat_normal(detector) -> np.ndarray | None:
    """The one normal a flat detector's points carry (what its ``sample`` returns), None if it is not flat."""
    n0 = np.asarray(detector.sample(np.full((1, 3), 0.5))[1][0], dtype=np.float64)
    normals = getattr(detector, "normals", None)
    if normals is not None and len(normals) and float(np.min(np.asarray(normals) @ n0)) < 1.0 - 1e-9:
        return None
    return n0


@dataclass(frozen=True, eq=False)
class EyeTable:
    """The eye chains' draw, learnt by a pilot (:func:`build_table`): which (detector, side) key a chain
    starts on (probability ``key_prob[2 j + (side < 0)]``, an inverse CDF of the chain's first uniform),
    and per key an entrance-style table (straylight.engine.entrance_sampling) over the two uniforms of the
    cosine map (radius sqrt(u1), azimuth 2 pi u2, the same structure as a disk source), or None (cosine
    there). The direction's pdf is q cos / pi, q = (P_key n_keys) x the key's table density: the key's
    share against the uniform 1 / n_keys is folded into q, so beta and the balance weights take it with
    the direction's. Flat detectors only: ``normals`` (one per detector) is the frame the tables are drawn in."""

    tables: tuple
    normals: np.ndarray
    pilot_eyes: int
    pilot_hits: int
    key_prob: np.ndarray  # (2 D,): P of each (detector, side) key; the back keys 0 when one side is counted
    n_keys: int  # D x sides: the keys a cosine draw picks uniformly
    family_w: float = float("nan")  # the pilot's estimate of the power its chains' family carries, W
    detected_w: float | None = None  # the entrance pilot's detected power it was weighed against, W
    #: False on the entrance pilot's copy (straylight.engine.entrance_sampling.build_table): its chains are traced
    #: and weigh the walk's trees as in the run, but their source connections, which do not depend on the ray's
    #: entrance point, are not counted
    source_connections: bool = True

    @property
    def key_cdf(self) -> np.ndarray:
        cdf = np.cumsum(self.key_prob)
        cdf[-1] = 1.0
        return cdf

    def keys(self, u0) -> tuple[np.ndarray, np.ndarray]:
        """Detector and side (+1 front, -1 back) of the chains whose first uniforms are ``u0`` (inverse CDF
        of :attr:`key_prob`: a key of probability 0 is never picked)."""
        cdf = self.key_cdf
        u0 = np.asarray(u0, np.float64)
        key = np.zeros(u0.shape, np.int64)
        for c in cdf:  # the CDF values <= u0 (np.searchsorted(cdf, u0, side="right") over a few keys)
            key += c <= u0
        key = np.minimum(key, len(cdf) - 1)
        return key // 2, np.where(key % 2 == 1, -1.0, 1.0)

    def _key(self, j, side):
        return 2 * np.asarray(j, np.int64) + (np.asarray(side) < 0)

    def key_factor(self, j, side) -> np.ndarray:
        """P_key n_keys of the chains' keys: the key's share of the chains over the uniform choice's."""
        return self.key_prob[self._key(j, side)] * self.n_keys

    def _groups(self, j, side):
        key = self._key(j, side)
        for kk in distinct(key):
            table = self.tables[int(kk)]
            if table is not None:
                g = np.flatnonzero(key == kk)
                yield table, (slice(None) if len(g) == len(key) else g)  # one key for all: no gather

    def warp(self, j, side, drawn) -> np.ndarray:
        """Move the cosine map's uniforms ``drawn`` (n, 2, in place) to the tables' density; returns q (n,)."""
        q = self.key_factor(j, side)
        for table, g in self._groups(j, side):
            if isinstance(g, slice):
                q = q / warp(table, drawn)
                continue
            sub = drawn[g]
            q[g] = q[g] / warp(table, sub)
            drawn[g] = sub
        return q

    def density(self, j, side, drawn) -> np.ndarray:
        """q at the cosine map's uniforms ``drawn`` (n, 2)."""
        q = self.key_factor(j, side)
        for table, g in self._groups(j, side):
            q[g] = q[g] * entrance_density(table, drawn[g])
        return q

    def density_of_arrival(self, j: int, arrival) -> np.ndarray:
        """q of the eye directions -``arrival`` (n, 3: forward directions reaching detector ``j``)."""
        eye = -np.asarray(arrival, dtype=np.float64)
        n0 = self.normals[j]
        side = np.where(eye @ n0 >= 0.0, 1.0, -1.0)
        nz = side[:, None] * n0[None, :]
        return self.density(np.full(len(eye), j), side, invert_cosine_hemisphere_sample(_local(eye, nz)))


@dataclass(frozen=True)
class EyesOff:
    """The eye pilot's verdict that the chains do not pay on this trace (:func:`verdict`): their family
    carries ``family_w`` (the pilot's source connections and once-scattered light, W) of the ``detected_w``
    the entrance pilot saw,
    measured with ``pilot_eyes`` chains. On the spec's ``eye_table``; the plan then turns the strategy off
    (:meth:`straylight.engine.strategies.reverse_chain.ReverseChainStrategy.declines`)."""

    family_w: float
    detected_w: float
    pilot_eyes: int
    scattered_w: float = 0.0  # of family_w, the light the beam scatters once before the end points (W)

    @property
    def share(self) -> float:
        return self.family_w / self.detected_w

    @property
    def reason(self) -> str:
        return (f"the eye pilot's chains carried {self.share:.2g} of the detected power ({self.pilot_eyes} chains, "
                f"below EYE_SHARE_OFF = {EYE_SHARE_OFF:g}): the walk counts their family")


def verdict(x, n_chains: int, detected_w: float | None, share_off: float | None = None) -> EyesOff | None:
    """:class:`EyesOff` when the eye pilot's chains (source-connection values ``x`` of ``n_chains`` chains:
    each an unbiased estimate of their family's power) carry less than ``share_off`` (default
    :data:`EYE_SHARE_OFF`) of ``detected_w``, the entrance pilot's detected power; None (the chains run)
    otherwise, and whenever that power is unknown, not positive or not finite."""
    share_off = EYE_SHARE_OFF if share_off is None else float(share_off)
    if detected_w is None or not np.isfinite(detected_w) or detected_w <= 0 or n_chains <= 0:
        return None
    family_w = float(np.sum(x)) / int(n_chains)
    if not np.isfinite(family_w) or family_w >= share_off * float(detected_w):
        return None
    return EyesOff(family_w=max(family_w, 0.0), detected_w=float(detected_w), pilot_eyes=int(n_chains))


def build_table(spec, scene, n_eyes: int = PILOT_EYES, detected_w: float | None = None) -> EyeTable | EyesOff | None:
    """Learn the eye chains' draw from a pilot of ``n_eyes`` eye chains (own streams, from
    :data:`PILOT_CHUNK_OFFSET`) joined to the source (module doc, "The eye table"): a first stage of
    :data:`PILOT_FIRST_EYES` cosine-drawn chains of uniform keys, the rest cosine-drawn too on keys drawn
    by the first stage's key probabilities. Per (detector, side) key, each chain's source-connection value
    brought to a uniform key's measure (x q) goes to its direction's cell, and the key's table is
    :func:`straylight.engine.entrance_sampling.table_from_contributions` of them; the keys get P_key
    proportional to the root of their chains' second moment under that table, a :data:`KEY_DEFENSIVE`
    share spread evenly. None when a detector is not flat, the source is linearly polarized or the first
    stage joined nothing (and ``detected_w`` is not known). With ``detected_w``, the entrance pilot's
    detected power, W: :class:`EyesOff` when the first stage's chains, or all of them, carry less than
    :data:`EYE_SHARE_OFF` of it (:func:`verdict`; module doc, "Where the chains pay")."""
    if unsupported(spec) is not None or _source_linear(spec):
        return None
    flat = [_flat_normal(d) for d in scene.detectors]
    if any(n is None for n in flat):
        return None
    normals = np.array(flat)
    est = spec.options.estimator
    k = max(int(est.reverse_chain), int(est.delta_chain))
    eyes = EyeChains(k, parts_with(spec, Capability.DELTA_CHAIN), scatter_ends(spec), reflection_limit(est))
    n = int(n_eyes)
    first = min(PILOT_FIRST_EYES // CHUNK_RAYS * CHUNK_RAYS, n)
    D = len(scene.detectors)
    both = spec.options.output.detector_sides == "both"
    stages = []
    values = []  # per stage: each chain's source-connection value x (an estimate of the family's power)
    kept = []  # per stage: its chains' end points (for the once-scattered light, :func:`_judge`)
    keys = None  # the first stage's key probabilities, cosine directions: the rest's draw
    for a, b in ((0, first), (first, n)):
        if b <= a:
            continue
        u_s = eye_uniforms(spec, a // CHUNK_RAYS, -(-b // CHUNK_RAYS), b - a, PILOT_CHUNK_OFFSET)
        ends, q, drawn_s = eyes.trace(spec, scene, u_s, keys)
        g, raw = source_connection(spec, scene, ends)[:2]
        x_s = np.bincount(ends.ray[g], weights=raw, minlength=b - a) if len(g) else np.zeros(b - a)
        j, side = chain_keys(u_s, D, both, keys)
        # x q: what the chain carries when its key is drawn uniformly (q = P_key n_keys here)
        stages.append((drawn_s, x_s * q, 2 * j + (side < 0)))
        values.append(x_s)
        kept.append(ends)
        if a == 0:
            off = _judge(spec, scene, eyes, values, kept, detected_w)
            if off is not None:
                return off  # the chains would carry too little of the light: the pilot ends here
            if not np.any(x_s > 0):
                return None  # the first stage joined nothing: no table (module doc)
            first_table = _learn(stages, normals, both, b)
            keys = replace(first_table, tables=(None,) * len(first_table.tables))
    x_all = np.concatenate(values)
    off = _judge(spec, scene, eyes, values, kept, detected_w)
    if off is not None:
        return off
    return replace(_learn(stages, normals, both, n), family_w=float(np.sum(x_all)) / n, detected_w=detected_w)


def chain_family(spec, events: np.ndarray) -> np.ndarray:
    """Of path records with event codes ``events`` (n, width: part x 4 + kind per event after the source, -1
    after the last; the detector not included): those of the family the eye chains count, "source -> P ->
    interfaces -> detector" or "source -> A -> P -> interfaces -> detector" with A and P plain scatterers (an
    end-point kind, :func:`scatter_ends`) and at least one interface (every event after P specular at a
    :attr:`Capability.DELTA_CHAIN` part, as far as the codes go). A record's own history only, not the chains'
    reach (K, R) or whether P received unpolarized light: the entrance pilot uses it to leave that family out of
    the contributions its first stage measured without the chains (straylight.engine.entrance_sampling)."""
    ev = np.asarray(events, dtype=np.int64)
    if ev.ndim != 2 or ev.shape[1] == 0 or len(ev) == 0:
        return np.zeros(len(ev), dtype=bool)
    part = np.where(ev >= 0, ev // 4, 0)
    kind = np.where(ev >= 0, ev % 4, -1)
    end = scatter_ends(spec)[np.asarray(spec.part_material)[part]] & (kind == EVENT_SCATTER)
    splits = np.asarray(parts_with(spec, Capability.DELTA_CHAIN), dtype=bool)[part] & (kind == EVENT_SPECULAR)
    width = ev.shape[1]
    p_at = np.where(end[:, 0] & (width > 1) & end[:, min(1, width - 1)], 1, 0)  # A -> P, or P first
    col = np.arange(width)[None, :]
    after = col > p_at[:, None]
    recorded = ev >= 0
    n_interfaces = np.sum(after & recorded & splits, axis=1)
    others = np.sum(after & recorded & ~splits, axis=1)
    return end[:, 0] & end[np.arange(len(ev)), p_at] & (n_interfaces >= 1) & (others == 0)


def once_scattered(spec, scene, ends, n_chains: int, splits, end_material, stream: int) -> np.ndarray:
    """Per chain (``n_chains``): an estimate of what the chains' end points ``ends`` send on of the light the
    beam scatters once before them (source -> A -> P, the vertex connections' family from the beam's own
    scatter points). From each P one direction w toward the light, cosine-distributed about n_P (its own
    stream, key ``stream``), cast; where it meets a plain scatter part A (an end-point kind, as the vertex
    connections need), A's source connection with the importance beta_P pi f_P(w, omega_P) (cosine
    sampling: f cos / (cos / pi)) and A's view back along -w gives the value; :data:`PILOT_SCATTER_DRAWS`
    directions per P, their mean."""
    out = np.zeros(int(n_chains))
    if len(ends.ray) == 0:
        return out
    m = PILOT_SCATTER_DRAWS
    e = np.repeat(np.arange(len(ends.ray)), m)  # each end point's draws
    rng = np.random.default_rng([int(spec.seed), int(PILOT_CHUNK_OFFSET - 1 - stream), STREAM])
    n_p = take_rows(ends.normal, e)
    t, b = orthonormal_basis(n_p)
    local = sample_cosine_hemisphere(rng.random((len(e), 2)))
    w = local[:, :1] * t + local[:, 1:2] * b + local[:, 2:3] * n_p
    w /= np.linalg.norm(w, axis=1)[:, None]
    origin = np.ascontiguousarray(take_rows(ends.point, e) + 2.0 * spec.eps * n_p)
    h = cast_branches(spec, scene, origin, np.ascontiguousarray(w))
    mat = spec.part_material[h.part]
    plain = (spec.part_roles[h.part] != ROLE_DETECTOR) & ~splits[h.part] & end_material[mat]
    rows, tri = h.hit[plain], h.tri[plain]
    if len(rows) == 0:
        return out
    nrm = take_rows(scene.normals, tri)
    facing = np.where((h.cos_in[plain] < 0)[:, None], nrm, -nrm)
    p = e[rows]
    f_p = _brdf(spec, ends.material[p], n_p[rows], w[rows], take_rows(ends.omega, p))
    beta = ends.beta[p] * np.pi * f_p / m
    ok = beta > 0
    if not ok.any():
        return out
    rows, p, z0 = rows[ok], p[ok], np.zeros(int(ok.sum()), np.int64)
    lit = EyeEnds(ends.ray[p], origin[rows] + h.distance_mm[plain][ok, None] * w[rows], facing[ok],
                  h.part[plain][ok], mat[plain][ok], -w[rows], beta[ok], z0, np.zeros((len(rows), 3)), z0,
                  np.zeros((len(rows), 1), np.int64), z0)
    g, raw = source_connection(spec, scene, lit)[:2]
    if len(g):
        np.add.at(out, lit.ray[g], raw)
    return out


def _judge(spec, scene, eyes: EyeChains, values, ends, detected_w) -> EyesOff | None:
    """:func:`verdict` on the pilot's stages so far (per stage: its chains' source-connection values and
    their end points); when the source connections alone say off, again with the light the beam scatters
    once before the end points added (:func:`once_scattered`): the chains stay on when that family carries
    the share."""
    x = np.concatenate(values)
    if verdict(x, len(x), detected_w) is None:
        return None
    scattered = np.concatenate([once_scattered(spec, scene, e, len(v), eyes.splits, eyes.end_material, stage)
                                for stage, (v, e) in enumerate(zip(values, ends))])
    off = verdict(x + scattered, len(x), detected_w)
    return None if off is None else replace(off, scattered_w=float(np.sum(scattered)) / len(x))


def _learn(stages, normals, both: bool, n_traced: int) -> EyeTable:
    """The :class:`EyeTable` of the pilot stages ``stages`` (per stage: the cosine-map uniforms (m, 2)
    of the chains' directions, their values x q at a uniform key's measure and their keys 2 j + (side < 0))."""
    drawn = np.concatenate([st[0] for st in stages])
    x = np.concatenate([st[1] for st in stages])
    key = np.concatenate([st[2] for st in stages])
    n_det = len(normals)
    tables = []
    moment = np.zeros(2 * n_det)  # per key: the mean of x^2 / q_dir, its chains' second moment under its table
    for kk in range(2 * n_det):
        sel = key == kk
        n_sel = int(np.count_nonzero(sel))
        # a key that holds every chain takes them as they are (no gather)
        drawn_k, x_k = (drawn, x) if n_sel == len(key) else (drawn[sel], x[sel])
        table = table_from_contributions(drawn_k, x_k) if n_sel else None
        tables.append(table)
        if table is not None:
            moment[kk] = float(np.mean(x_k ** 2 / entrance_density(table, drawn_k)))
    counted = np.ones(2 * n_det, dtype=bool) if both else (np.arange(2 * n_det) % 2 == 0)
    root = np.sqrt(moment)
    n_keys = int(counted.sum())
    prob = np.where(counted, KEY_DEFENSIVE / n_keys + (1.0 - KEY_DEFENSIVE) * root / root.sum(), 0.0)
    return EyeTable(tables=tuple(tables), normals=normals, pilot_eyes=n_traced,
                    pilot_hits=int(np.count_nonzero(x)), key_prob=prob / prob.sum(), n_keys=n_keys)


class EyeEnds:
    """End points of the batch's eye chains, sorted by the ray that owns them."""

    def __init__(self, ray, point, normal, part, material, omega, beta, detector, z, k, codes, refl, q=None,
                 presorted: bool = False):
        # presorted: ``ray`` is already non-decreasing (the stable sort would keep every row where it is)
        order = slice(None) if presorted else np.argsort(ray, kind="stable")
        self.ray, self.point, self.normal = ray[order], take_rows(point, order), take_rows(normal, order)
        self.part, self.material, self.omega = part[order], material[order], take_rows(omega, order)
        self.beta, self.detector, self.z, self.k = beta[order], detector[order], take_rows(z, order), k[order]
        self.codes = take_rows(codes, order)  # (m, K) interface codes in the forward order, -1 padded
        self.refl = refl[order]  # reflections among the k interfaces
        # the density factor of the chain's direction draw (its pdf q cos / pi: the eye table's)
        self.q = (np.ones(len(ray)) if q is None else np.asarray(q, dtype=np.float64))[order]

    def per_ray(self, eyes_per_ray: int, q_chain: np.ndarray) -> "EyeEnds":
        """These ends (of chains numbered c) regrouped by ray c // ``eyes_per_ray``, each chain's weight
        divided by ``eyes_per_ray`` (the ray's estimate is their mean), with the chains' q."""
        m = int(eyes_per_ray)
        c = self.ray
        return EyeEnds(c // m, self.point, self.normal, self.part, self.material, self.omega, self.beta / m,
                       self.detector, self.z, self.k, self.codes, self.refl, q=q_chain[c], presorted=True)


class _Branches:
    """Eye rays in flight: owning ray, origin, direction, scalar weight, Stokes covector and its
    frame e1, interfaces met, last part, detector and point where the chain started, codes,
    reflections met."""

    FIELDS = ("ray", "origin", "d", "w", "v", "e1", "k", "last_part", "det", "z", "codes", "refl")

    def __init__(self, **kw):
        for f in self.FIELDS:
            setattr(self, f, kw[f])

    def take(self, sel):
        return _Branches(**{f: take_rows(getattr(self, f), sel) for f in self.FIELDS})

    @classmethod
    def concat(cls, parts):
        return cls(**{f: concat_codes([p.codes for p in parts]) if f == "codes"
                      else np.concatenate([getattr(p, f) for p in parts]) for f in cls.FIELDS})


def chain_keys(u, n_detectors: int, both: bool, table) -> tuple[np.ndarray, np.ndarray]:
    """Detector j and side (+1 front, -1 back) of the eye chains of uniforms ``u`` (n, 7): without a
    table, u0 picks the detector uniformly and u5 < 0.5 the front (both sides counted); with one, u0
    picks the (detector, side) key by the table's key probabilities (:meth:`EyeTable.keys`)."""
    if table is not None:
        return table.keys(u[:, 0])
    j = np.minimum((u[:, 0] * n_detectors).astype(np.int64), n_detectors - 1)
    return j, (np.where(u[:, 5] < 0.5, 1.0, -1.0) if both else np.ones(len(u)))


def reflection_limit(est) -> int:
    """The reflections an eye chain follows: the split trees' ``delta_chain_reflections`` R when the
    trees run with one (the chains must reach every path a tree does, and need not go further),
    else 0 (no limit)."""
    return int(est.delta_chain_reflections) if int(est.delta_chain) > 0 else 0


class EyeChains:
    """Eye chains through up to ``k_max`` interfaces (``splits``: bool per part, the parts crossed),
    at most ``r_max`` of them reflections (0: no limit), ending at plain scatter parts
    (``end_material``: bool per material, :func:`scatter_ends`); :attr:`shadow_rays` counts the casts."""

    compiled = True  # False: the numpy twins (start_rays_numpy, _onward_numpy), the reference for the tests

    def __init__(self, k_max: int, splits: np.ndarray, end_material: np.ndarray, r_max: int = 0):
        self.k_max = int(k_max)
        self.r_max = int(r_max) if int(r_max) > 0 else self.k_max
        self.splits = splits
        self.end_material = end_material
        self.shadow_rays = 0

    def trace(self, spec, scene, u, table):
        """The eye chains of uniforms ``u`` (n, 7), one per row (its "ray"), directions drawn by
        ``table`` (an :class:`EyeTable`; None: cosine): their :class:`EyeEnds`, the density factor
        q of each row's direction draw (its pdf is q cos / pi) and the uniforms (n, 2) that drew it
        from the cosine map (before the table's warp)."""
        n = len(u)
        dets = scene.detectors
        D = len(dets)
        both = spec.options.output.detector_sides == "both"
        j, side = chain_keys(u, D, both, table)
        z = np.empty((n, 3))
        nz = np.empty((n, 3))
        area = np.empty(n)
        for jj in range(D):
            g = np.flatnonzero(j == jj)
            if len(g) == n:  # every chain on this detector: no gather, no scatter
                z, nz = dets[jj].sample(u[:, 1:4])
                area[:] = dets[jj].area_mm2
            elif len(g):
                z[g], nz[g] = dets[jj].sample(u[g, 1:4])
                area[g] = dets[jj].area_mm2
        if table is not None:  # flat detectors: the frame the tables were drawn in
            nz = table.normals[j].copy()
        nz = nz * side[:, None]
        # cosine-weighted direction about nz (density cos / pi); with both sides counted, u5 picks the
        # side (< 0.5, without a table) and its doubled fraction is the azimuth's uniform
        azimuth_u = u[:, 5] * 2.0 % 1.0 if both else u[:, 5]
        drawn = np.ascontiguousarray(np.stack([u[:, 4], azimuth_u], axis=1))
        q = np.ones(n)
        if table is not None:
            q = table.warp(j, side, drawn)
        # the direction, its frame e1 (any frame: the covector (1, 0, 0, 0) is the same in all) and the origin
        d, e1, origin = (start_rays if self.compiled else start_rays_numpy)(drawn, nz, z, 2.0 * spec.eps)
        beta = np.pi * area * D * (2.0 if both else 1.0) / q
        det_part = np.asarray(scene.det_parts, dtype=np.int64)[j]
        width = max(min(self.k_max, CODE_COLUMNS), 1)
        if self.compiled:  # no rows: every chain starts with the covector (1, 0, 0, 0) and no codes (_onward_loop)
            v, codes = np.zeros((0, 4)), np.full((0, width), -1, dtype=np.int64)
        else:
            v, codes = np.zeros((n, 4)), np.full((n, width), -1, dtype=np.int64)
            v[:, 0] = 1.0
        live = _Branches(ray=np.arange(n), origin=origin, d=d, w=beta, v=v,
                         e1=e1, k=np.zeros(n, np.int64), last_part=det_part, det=j, z=z, codes=codes,
                         refl=np.zeros(n, np.int64))
        ends = []
        for _ in range(int(spec.options.physics.max_events)):
            if live is None or len(live.w) == 0:
                break
            live = self._step(spec, scene, live, ends)
        if not ends:
            z0 = np.empty(0, np.int64)
            return EyeEnds(z0, np.empty((0, 3)), np.empty((0, 3)), z0, z0, np.empty((0, 3)), np.empty(0), z0,
                           np.empty((0, 3)), z0, np.empty((0, max(self.k_max, 1)), np.int64), z0), q, drawn
        cols = {k: concat_codes([e[k] for e in ends]) if k == "codes" else np.concatenate([e[k] for e in ends])
                for k in ends[0]}
        return EyeEnds(**cols), q, drawn

    def _step(self, spec, scene, b, ends):
        h = cast_branches(spec, scene, np.ascontiguousarray(b.origin), np.ascontiguousarray(b.d))
        self.shadow_rays += len(b.w)
        hit, tri, dist, part, cos_in = h.hit, h.tri, h.distance_mm, h.part, h.cos_in  # rows of b: hit
        det = spec.part_roles[part] == ROLE_DETECTOR
        # an end point: a plain scatter part met after >= 1 interface
        mat = spec.part_material[part]
        end = np.flatnonzero(~det & ~self.splits[part] & (b.k[hit] >= 1) & self.end_material[mat])
        if len(end):
            rows = hit[end]
            beta = b.w[rows] * b.v[rows, 0]
            ok = np.flatnonzero(beta > 0)
            if len(ok):  # only the end points that carry something are gathered
                end, rows, beta = end[ok], rows[ok], beta[ok]
                nrm = take_rows(scene.normals, tri[end])
                facing = np.where((cos_in[end] < 0)[:, None], nrm, -nrm)
                d_end = take_rows(b.d, rows)
                point = take_rows(b.origin, rows) + dist[end, None] * d_end
                k_end = b.k[rows]
                ends.append({"ray": b.ray[rows], "point": point, "normal": facing, "part": part[end],
                             "material": mat[end], "omega": -d_end, "beta": beta, "detector": b.det[rows],
                             "z": take_rows(b.z, rows), "k": k_end, "codes": _forward_codes(take_rows(b.codes, rows), k_end),
                             "refl": b.refl[rows]})
        go = np.flatnonzero(~det & self.splits[part])
        if len(go) == 0:
            return None
        idx = hit[go]  # rows of b going on (taken once per branch set below: no copy of the rest)
        part, dist, cos_in, tri = part[go], dist[go], cos_in[go], tri[go]
        origin, d = take_rows(b.origin, idx), take_rows(b.d, idx)
        front, facing, at, passing = at_interfaces(spec, scene, part, tri, origin, d, dist, b.last_part[idx], cos_in)
        if not self.compiled:
            return self._onward_numpy(spec, b, idx, part, dist, front, facing, at, passing, d)
        through = np.flatnonzero(passing)
        live = np.flatnonzero(~passing & (b.k[idx] < self.k_max))
        sel = idx[live]
        n = len(live)
        fresnel = branch_coefficients(spec, part[live], front[live], take_rows(d, live), take_rows(facing, live),
                                      dist[live]) if n else (np.zeros(0, complex),) * 4 + (np.zeros(0),) * 3
        rs, rp, ts, tp, cos_t, eta, bulk = (_rows(x, n, t) for x, t in zip(fresnel, (complex,) * 4 + (float,) * 3))
        out = lazy_njit(_onward_loop, "numpy")(
            np.ascontiguousarray(idx[through], np.int64), _f64(take_rows(at, through)), part[through],
            np.ascontiguousarray(sel, np.int64), _f64(take_rows(at, live)), _f64(take_rows(facing, live)), part[live],
            np.abs(rs) ** 2, np.abs(rp) ** 2, rs * np.conj(rp), np.abs(ts) ** 2, np.abs(tp) ** 2, ts * np.conj(tp),
            cos_t, eta, bulk, 2.0 * spec.eps, self.r_max, b.ray, _f64(b.d), b.w, _f64(b.v), _f64(b.e1), b.k, b.det,
            _f64(b.z), np.ascontiguousarray(b.codes), b.refl)
        if len(out[0]) == 0:
            return None
        return _Branches(**dict(zip(_Branches.FIELDS, out)))

    def _onward_numpy(self, spec, b, idx, part, dist, front, facing, at, passing, d):
        """The branches going on from the interface hits ``idx`` (rows of ``b``) in numpy (the reference
        :func:`_onward_loop` is tested against): the pass-throughs, then :meth:`_children`."""
        out = []
        through = np.flatnonzero(passing)
        if len(through):  # a pass-through: the walk goes on unchanged, and so does the chain
            c = b.take(idx[through])
            c.origin = np.ascontiguousarray(take_rows(at, through) + 2.0 * spec.eps * c.d)
            c.last_part = part[through]
            out.append(c)
        live = np.flatnonzero(~passing & (b.k[idx] < self.k_max))
        if len(live):
            out.extend(self._children(spec, b.take(idx[live]), part[live], take_rows(at, live),
                                      take_rows(facing, live), dist[live], front[live]))
        out = [o for o in out if len(o.w)]
        if not out:
            return None
        return out[0] if len(out) == 1 else _Branches.concat(out)

    def _children(self, spec, b, part, at, facing, dist, front):
        """Reflected and transmitted eye branches at interface hits, the covector carried back."""
        rs, rp, ts, tp, cos_t, eta, bulk = branch_coefficients(spec, part, front, b.d, facing, dist)
        m = len(part)
        s = s_vector(b.d, facing)
        # the covector from the frame of the interface met before (forward: after) to this one's s
        # frame, along the forward direction -d (the inverse of the forward rotation)
        v = rotate_stokes(b.v, b.e1, s, -b.d)
        code = part * 4 + EVENT_SPECULAR
        codes = widen_codes(b.codes, int(b.k.max()) + 1 if m else 0)
        codes = codes.copy() if codes is b.codes else codes
        codes[np.arange(m), b.k] = code
        eps = 2.0 * spec.eps
        out = []
        for a_s, a_p, sign in ((rs, rp, 1.0), (ts, tp, -1.0)):
            v_in = apply_interface_mueller(a_s, a_p, v, transpose=True)  # M^T v
            w = b.w * bulk
            g = np.flatnonzero((v_in[:, 0] > 0) & (w > 0) & ((b.refl < self.r_max) if sign > 0 else True))
            if len(g) == 0:
                continue
            d_g, facing_g = take_rows(b.d, g), take_rows(facing, g)
            d_out = reflect(d_g, facing_g) if sign > 0 else refract(d_g, facing_g, eta[g], cos_t[g])
            out.append(_Branches(ray=b.ray[g], origin=np.ascontiguousarray(take_rows(at, g) + sign * eps * facing_g),
                                 d=np.ascontiguousarray(d_out), w=w[g], v=take_rows(v_in, g), e1=take_rows(s, g),
                                 k=b.k[g] + 1, last_part=part[g], det=b.det[g], z=take_rows(b.z, g),
                                 codes=take_rows(codes, g),
                                 refl=b.refl[g] + (1 if sign > 0 else 0)))
        return out


def _f64(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


def _rows(a, n, dtype) -> np.ndarray:
    """``a`` as a contiguous (n,) array of ``dtype`` (a scalar broadcast)."""
    a = np.asarray(a, dtype=dtype)
    return np.ascontiguousarray(a if a.shape == (n,) else np.broadcast_to(a, (n,)))


def start_rays(drawn, nz, z, eps):
    """The eye chains' first rays: directions cosine-drawn about ``nz`` (n, 3) from the cosine map's
    uniforms ``drawn`` (n, 2), their s-frame vectors ``s_vector(d, nz)`` and origins ``z + eps nz``. One
    compiled pass (:func:`_start_rays_loop`) over :func:`start_rays_numpy`'s operations in its order (the
    same bits)."""
    n = len(drawn)
    d, e1, origin = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3))
    if n:
        lazy_njit(_start_rays_loop, "numpy")(_f64(drawn), _f64(nz), _f64(z), float(eps), d, e1, origin)
    return d, e1, origin


def start_rays_numpy(drawn, nz, z, eps):
    """:func:`start_rays` as separate numpy passes (the reference it is tested against)."""
    local = sample_cosine_hemisphere(drawn)
    t, b = orthonormal_basis(nz)
    d = local[:, :1] * t + local[:, 1:2] * b + local[:, 2:3] * nz
    d /= np.linalg.norm(d, axis=1)[:, None]
    return d, s_vector(d, nz), np.ascontiguousarray(z + eps * nz)


_TWO_PI = 2.0 * np.pi


def _start_rays_loop(drawn, nz, z, eps, d, e1, origin):
    """:func:`start_rays_numpy` row by row: materials.sampling's ``_cosine_hemisphere_loop``,
    sources.orthonormal_basis, ``np.linalg.norm``'s ``(x0^2 + x1^2) + x2^2`` and materials.mueller's
    ``_s_vector_loop`` written out in their order."""
    for r in range(len(drawn)):
        rad = math.sqrt(drawn[r, 0])
        phi = _TWO_PI * drawn[r, 1]
        l0 = rad * math.cos(phi)
        l1 = rad * math.sin(phi)
        l2 = math.sqrt(max(0.0, 1.0 - rad * rad))
        x, y, zz = nz[r, 0], nz[r, 1], nz[r, 2]
        t0, t1, t2, b0, b1, b2 = tangent_frame(x, y, zz)
        d0 = (l0 * t0 + l1 * b0) + l2 * x
        d1 = (l0 * t1 + l1 * b1) + l2 * y
        d2 = (l0 * t2 + l1 * b2) + l2 * zz
        norm = np.sqrt((d0 * d0 + d1 * d1) + d2 * d2)
        d0, d1, d2 = d0 / norm, d1 / norm, d2 / norm
        d[r, 0], d[r, 1], d[r, 2] = d0, d1, d2
        e1[r, 0], e1[r, 1], e1[r, 2] = unit_s_vector(d0, d1, d2, x, y, zz)
        for c in range(3):
            origin[r, c] = z[r, c] + eps * nz[r, c]


def _onward_loop(through, at_through, part_through, sel, at, facing, part, ss_r, pp_r, c_r, ss_t, pp_t, c_t, cos_t,
                 eta, bulk, eps, r_max, ray, d, w, v, e1, k, det, z, codes, refl):
    """:meth:`EyeChains._onward_numpy` row by row: the pass-throughs ``through`` (rows of the branches,
    moved ``eps`` past their hits ``at_through``), then the reflections of the rows ``sel`` (hits ``at``,
    facing normals ``facing``) in row order, then their transmissions; materials.mueller's
    ``_s_vector_loop``, ``_rotate_stokes_loop`` (along -d) and ``_apply_interface_loop`` (transposed),
    materials.smooth's ``_reflect_loop`` / ``_refract_loop`` written out in their order. ``v`` and
    ``codes`` without rows: the chains' first rays, each with the covector (1, 0, 0, 0) and no codes
    (nothing to allocate per chain). Returns the fields of :class:`_Branches` in :attr:`_Branches.FIELDS`
    order."""
    n = len(sel)
    fresh = len(v) == 0  # the chains' first rays: covector (1, 0, 0, 0), no codes (v and codes without rows)
    vo = np.empty((2, n, 4))
    s_out = np.empty((n, 3))
    take = np.zeros((2, n), np.bool_)
    m = len(through)
    k_top = -1
    for r in range(n):
        i = sel[r]
        k_top = max(k_top, k[i])
        d0, d1, d2 = d[i, 0], d[i, 1], d[i, 2]
        n0, n1, n2 = facing[r, 0], facing[r, 1], facing[r, 2]
        c0, c1, c2 = unit_s_vector(d0, d1, d2, n0, n1, n2)
        s_out[r, 0], s_out[r, 1], s_out[r, 2] = c0, c1, c2
        cc, ss = frame_rotation(e1[i, 0], e1[i, 1], e1[i, 2], -d0, -d1, -d2, c0, c1, c2)  # rotate_stokes(v, e1, s, -d)
        if fresh:
            v0, v1, v2, v3 = 1.0, 0.0, 0.0, 0.0
        else:
            v0, v1, v2, v3 = v[i, 0], v[i, 1], v[i, 2], v[i, 3]
        v1, v2 = cc * v1 + ss * v2, -ss * v1 + cc * v2
        wb = w[i] * bulk[r]
        for b in range(2):
            if b == 0:
                A, B, C, D = 0.5 * (ss_r[r] + pp_r[r]), 0.5 * (ss_r[r] - pp_r[r]), c_r[r].real, c_r[r].imag
            else:
                A, B, C, D = 0.5 * (ss_t[r] + pp_t[r]), 0.5 * (ss_t[r] - pp_t[r]), c_t[r].real, c_t[r].imag
            D23, D32 = -D, D  # M^T: the covector carried back
            vo[b, r, 0] = (((0.0 + A * v0) + B * v1) + 0.0 * v2) + 0.0 * v3
            vo[b, r, 1] = (((0.0 + B * v0) + A * v1) + 0.0 * v2) + 0.0 * v3
            vo[b, r, 2] = (((0.0 + 0.0 * v0) + 0.0 * v1) + C * v2) + D23 * v3
            vo[b, r, 3] = (((0.0 + 0.0 * v0) + 0.0 * v1) + D32 * v2) + C * v3
            if vo[b, r, 0] > 0 and wb > 0 and (b == 1 or refl[i] < r_max):
                take[b, r] = True
                m += 1
    width = codes.shape[1]
    if m > len(through):  # a child: the codes are widened to the live rows' deepest column (as widen_codes)
        width = max(width, k_top + 1)
    o_ray = np.empty(m, np.int64)
    o_origin = np.empty((m, 3))
    o_d = np.empty((m, 3))
    o_w = np.empty(m)
    o_v = np.empty((m, 4))
    o_e1 = np.empty((m, 3))
    o_k = np.empty(m, np.int64)
    o_part = np.empty(m, np.int64)
    o_det = np.empty(m, np.int64)
    o_z = np.empty((m, 3))
    o_codes = np.full((m, width), -1, np.int64)
    o_refl = np.empty(m, np.int64)
    for j in range(len(through)):
        i = through[j]
        o_ray[j] = ray[i]
        for c in range(3):
            o_origin[j, c] = at_through[j, c] + eps * d[i, c]
            o_d[j, c] = d[i, c]
            o_e1[j, c] = e1[i, c]
            o_z[j, c] = z[i, c]
        o_w[j] = w[i]
        for c in range(4):
            o_v[j, c] = (1.0 if c == 0 else 0.0) if fresh else v[i, c]
        o_k[j] = k[i]
        o_part[j] = part_through[j]
        o_det[j] = det[i]
        if not fresh:
            for c in range(codes.shape[1]):
                o_codes[j, c] = codes[i, c]
        o_refl[j] = refl[i]
    j = len(through)
    for b in range(2):
        step = (1.0 if b == 0 else -1.0) * eps
        for r in range(n):
            if not take[b, r]:
                continue
            i = sel[r]
            o_ray[j] = ray[i]
            f0, f1, f2 = facing[r, 0], facing[r, 1], facing[r, 2]
            o_origin[j, 0] = at[r, 0] + step * f0
            o_origin[j, 1] = at[r, 1] + step * f1
            o_origin[j, 2] = at[r, 2] + step * f2
            o_d[j, 0], o_d[j, 1], o_d[j, 2] = deflected(d[i, 0], d[i, 1], d[i, 2], f0, f1, f2, b == 0, eta[r], cos_t[r])
            o_w[j] = w[i] * bulk[r]
            for c in range(4):
                o_v[j, c] = vo[b, r, c]
            for c in range(3):
                o_e1[j, c] = s_out[r, c]
                o_z[j, c] = z[i, c]
            o_k[j] = k[i] + 1
            o_part[j] = part[r]
            o_det[j] = det[i]
            if not fresh:
                for c in range(codes.shape[1]):
                    o_codes[j, c] = codes[i, c]
            o_codes[j, k[i]] = part[r] * 4 + EVENT_SPECULAR_CODE
            o_refl[j] = refl[i] + (1 if b == 0 else 0)
            j += 1
    return o_ray, o_origin, o_d, o_w, o_v, o_e1, o_k, o_part, o_det, o_z, o_codes, o_refl


EVENT_SPECULAR_CODE = int(EVENT_SPECULAR)


class ReverseChains:
    """Per batch: the eye chains of its rays, the source connections of their end points (counted
    at once), the walk-side state that decides which walk paths the chains own, and the vertex
    connections from the walk's scatter vertices."""

    def __init__(self, ctx, k_max: int, splits: np.ndarray):
        spec, scene = ctx.spec, ctx.scene
        self.k_max = int(k_max)
        r_max = reflection_limit(spec.options.estimator)  # the chains' reflections (0: no limit)
        self.r_max = r_max if r_max > 0 else self.k_max
        self.path_depth = int(spec.options.output.path_depth)
        self.splits = splits  # bool per part: an interface the chains cross (Capability.DELTA_CHAIN)
        self.end_material = scatter_ends(spec)
        n = ctx.n_rays
        self.scale = 1.0 / float(spec.n_rays)  # each ray's eye chain: its 1/N share of the estimate
        # walk side, per ray: the segment started at the source or at a plain scatter vertex (pred);
        # the last scatter vertex is an end-point kind reached so (anchor); interfaces since (run)
        self.linear_source = _source_linear(spec)
        self.pred = np.full(n, not self.linear_source, dtype=bool)
        self._arriving_unpolarized = np.zeros(0, dtype=bool)  # per continuing hit of the current event
        self.anchor = np.zeros(n, dtype=bool)
        self.run = np.zeros(n, dtype=np.int64)
        self.refl = np.zeros(n, dtype=np.int64)  # reflections among the run's interfaces
        self.shadow_rays = 0
        # multiple importance sampling with the split trees (delta_chain), which count the same runs
        # from the walk's side: balance heuristic over (P, omega) (module doc, "Weights")
        est = spec.options.estimator
        self.k_tree = int(est.delta_chain)
        # the trees' reflection limit (delta_chain_reflections; 0: none): paths past it are not theirs
        self.r_tree = int(est.delta_chain_reflections) if int(est.delta_chain_reflections) > 0 else self.k_tree
        self.det_area = np.array([g.area_mm2 for g in scene.detectors], dtype=np.float64)
        self.sides = 2.0 if spec.options.output.detector_sides == "both" else 1.0
        self.w0 = ctx.start_weight_w
        src = spec.sources[0]
        self.source_footprint = _beam_footprint(src)
        self.p_walk = np.zeros(n)  # per anchored ray: the walk's density of (P, omega) (area x solid angle)
        self.cos_out = np.zeros(n)  # and the cosine of omega at P
        self.ends = self._trace_eyes(ctx)
        # the ends are sorted by ray: ray r's are first[r] .. first[r] + count[r] - 1
        self.count = np.bincount(self.ends.ray, minlength=n).astype(np.int64)
        self.first = np.cumsum(self.count) - self.count
        # the source connections are joined at the batch's first event, when every strategy's state is there:
        # their balance weight counts the walk's draws at P (straylight.engine.tree_split)
        self._ctx = ctx

    # ------------------------------------------------------------------ eye chains

    def _trace_eyes(self, ctx):
        spec = ctx.spec
        m = EYES_PER_RAY
        u = eye_uniforms(spec, ctx.first_chunk, ctx.stop_chunk, ctx.n_rays, spec.chunk_offset, per_ray=m)
        self.u_choice = u[::m, 6].copy()
        eyes = EyeChains(self.k_max, self.splits, self.end_material, self.r_max)
        ends, q, _ = eyes.trace(spec, ctx.scene, u, spec.eye_table)
        self.shadow_rays += eyes.shadow_rays
        return ends.per_ray(m, q)

    # ------------------------------------------------------------------ source connection

    def connect_source(self, states) -> None:
        """Join the end points to the source, once per batch (the batch's first event; ``states``: the
        batch's strategy states, whose split trees say how many draws the walk makes at P)."""
        ctx, self._ctx = self._ctx, None
        if ctx is not None:
            self._connect_source(ctx, states)

    def check_joined(self) -> None:
        """After the walk: the source connections were joined (a batch with rays has a first event)."""
        if self._ctx is not None and len(self.ends.ray):
            raise RuntimeError("reverse chains: the batch ended before its first event; its source connections were not joined")

    def _connect_source(self, ctx, states):
        e = self.ends
        if len(e.ray) == 0 or self.linear_source:  # P must receive unpolarized light (module doc)
            return
        table = ctx.spec.eye_table
        if table is not None and not table.source_connections:  # the entrance pilot's view (EyeTable)
            return
        g, raw, p_walk, shadows, p_area = source_connection(ctx.spec, ctx.scene, e)
        self.shadow_rays += shadows
        if len(g) == 0:
            return
        trees = states.get("delta_chain")
        split = getattr(trees, "lobe_split", None)
        if split is not None:  # P lit straight by the source: the walk's K draws there (tree_split)
            draws = np.ones(len(g))
            for j in distinct(e.detector[g]):
                m = np.flatnonzero(e.detector[g] == j)
                draws[m] = split.draws_at_source_points(states, e.material[g[m]], e.part[g[m]], e.k[g[m]],
                                                        e.codes[g[m]], int(j))
            p_walk = p_walk * draws
        nee = states.get("specular_nee")
        if nee is not None and nee.ghosts_shared(states):  # the ghost connections make some of these paths too
            p_walk = p_walk + nee.ghost_density_at_ends(ctx.spec, ctx.scene, e, g, p_area)
        value = raw * self.scale * self._eye_weight(g, p_walk)
        keep = value > 0
        g, value = g[keep], value[keep]
        self._tally(ctx.tallies, ctx.rows, ctx.records, e.ray[g], e.part[g], g, value, None, None, None)

    # ------------------------------------------------------------------ the walk's side

    def after_hits(self, event, cont):
        """Before the interactions: does each continuing hit receive unpolarized light, in the walk's
        model (no valid Stokes state for the ray at this depth, and not a linear source's first hit)?
        At the batch's first event, the source connections (:meth:`connect_source`)."""
        if self._ctx is not None:
            self.connect_source(event.states)
        rays = event.rays
        depth = rays.depth[cont]
        polarized = np.zeros(len(cont), dtype=bool)
        st = event.records.polarization
        if st is not None:
            polarized |= st.depth[rays.ray[cont]] == depth
        if self.linear_source:
            polarized |= depth == 0
        self._arriving_unpolarized = ~polarized

    def after_interactions(self, event, cont, out):
        """Update the per-ray state from what the continuing hits ``cont`` did (``out``: their
        Outgoing) and join the plain scatter vertices among them to their ray's end points."""
        if len(cont) == 0:
            return
        rays, hit = event.rays, event.hits
        r = rays.ray[cont]
        part = hit.part[cont].astype(np.int64)
        interface = self.splits[part]
        passing = np.zeros(len(cont), dtype=bool)  # an interface hit the walk passed unchanged
        at = np.flatnonzero(interface)
        if len(at):
            c = cont[at]
            passing[at] = (out.event[at] == rays.last_event[c]) & (out.throughput[at] == 1.0) \
                & (out.direction[at] == take_rows(rays.direction, c)).all(axis=1)
        mat = event.spec.part_material[part]
        scatter = (out.event == EVENT_SCATTER) & ~passing
        specular = (out.event == EVENT_SPECULAR) & interface & ~passing
        other = ~scatter & ~specular & ~passing
        # a plain scatterer's vertex (every arrival there scatters): joined to an end point whatever
        # the walk's own draw did next
        plain = scatter & ~interface & self.end_material[mat] & self._arriving_unpolarized
        self._connect_vertices(event, cont[plain])
        end_kind = scatter & ~interface & self.end_material[mat]
        anchored = end_kind & self.pred[r]
        if self.k_tree > 0 and anchored.any():
            self._walk_density(event, cont[anchored], out, np.flatnonzero(anchored))
        r_scatter, r_specular, r_other = r[scatter], r[specular], r[other]
        self.anchor[r_scatter] = anchored[scatter]
        self.run[r_scatter] = 0
        self.refl[r_scatter] = 0
        self.pred[r_scatter] = plain[scatter]
        self.run[r_specular] += 1
        self.refl[r_specular] += out.side[specular] > 0  # the walk's branch: a reflection leaves on its own side
        self.pred[r[specular | passing]] = False
        self.anchor[r_other] = False
        self.pred[r_other] = False
        self.run[r_other] = 0
        self.refl[r_other] = 0

    def _walk_density(self, event, rows, out, at):
        """The walk's density of the (P, omega) it drew at the anchored vertices ``rows`` (``out``
        rows ``at``): the area density of P (the beam's footprint, over the entrance density the
        ray's start weight carries; or the last vertex's direction pdf x |cos_P| / d^2) times the
        pdf of omega; and cos(omega, n_P)."""
        rays, hit = event.rays, event.hits
        r = rays.ray[rows]
        n_p = take_rows(hit.facing_normal, rows)
        from_source = rays.last_event[rows] == 0  # EVENT_SOURCE: P is the ray's first vertex
        d = take_rows(rays.direction, rows)
        beam = beam_density(self.w0, rays.weight_w[rows], d, n_p, self.source_footprint)
        dist = hit.distance_mm[rows]
        vertex = rays.last_pdf_per_sr[rows] * np.abs(hit.cos_in[rows]) / (dist * dist)
        self.p_walk[r] = np.where(from_source, beam, vertex) * out.pdf_per_sr[at]
        self.cos_out[r] = _dot(out.direction[at], n_p)

    def _eye_weight(self, k, p_walk) -> np.ndarray:
        """Balance-heuristic weight of the eye side for end points ``k`` whose path the walk draws
        with density ``p_walk`` (1 without split trees, or past their reach: more than K interfaces or
        more than R reflections)."""
        e = self.ends
        if self.k_tree <= 0:
            return np.ones(len(k))
        p_eye = EYES_PER_RAY * np.maximum(_dot(e.omega[k], e.normal[k]), 0.0) * e.q[k] \
            / (np.pi * self.det_area[e.detector[k]] * len(self.det_area) * self.sides)
        total = p_eye + p_walk
        w = np.where(total > 0, p_eye / np.where(total > 0, total, 1.0), 1.0)
        return np.where((e.k[k] <= self.k_tree) & (e.refl[k] <= self.r_tree), w, 1.0)

    def tree_share(self, event, rows, detector: int, arrival, walk_draws=None) -> np.ndarray:
        """The share a split tree rooted at ``rows`` keeps on ``detector``, its branches arriving along
        ``arrival`` (n, 3) (its balance weight against the eye side, whose direction density there
        the eye table gives; 1 for runs the chains do not own); ``walk_draws``: the walk's draws of such
        directions at the vertex (straylight.engine.tree_split; None: one)."""
        r = event.rays.ray[rows]
        p_walk = self.p_walk[r] if walk_draws is None else self.p_walk[r] * walk_draws
        return self.share_of(event, self.owns(event, rows, extra=1), p_walk, self.cos_out[r], detector, arrival)

    def eye_density(self, event, owned, cos_out, detector: int, arrival) -> np.ndarray:
        """The eye chains' density of walk-side paths (P, omega) (cos(omega, n_P) ``cos_out``) reaching
        ``detector`` along ``arrival``, on the (P, omega) measure the walk's densities use (``owned``: the rows
        the eye table's direction density applies to)."""
        p_eye = EYES_PER_RAY * np.maximum(cos_out, 0.0) \
            / (np.pi * self.det_area[detector] * len(self.det_area) * self.sides)
        table = event.spec.eye_table
        if table is not None and owned.any():
            p_eye = p_eye * np.where(owned, table.density_of_arrival(detector, arrival), 1.0)
        return p_eye

    def share_of(self, event, owned, p_walk, cos_out, detector: int, arrival) -> np.ndarray:
        """The balance weight p_walk / (p_walk + p_eye) of walk-side paths (P, omega) of density ``p_walk``
        (cos(omega, n_P) ``cos_out``) reaching ``detector`` along ``arrival``; 1 where not ``owned``."""
        p_eye = self.eye_density(event, owned, cos_out, detector, arrival)
        total = p_walk + p_eye
        share = np.where(total > 0, p_walk / np.where(total > 0, total, 1.0), 0.0)
        return np.where(owned, share, 1.0)

    def owns(self, event, rows, extra: int = 0) -> np.ndarray:
        """Of the rows ``rows``: the ray's last scatter is an anchored end-point kind and its run,
        with ``extra`` more interfaces, is within 1..K, with at most R reflections so far (paths the
        chains count; a split tree rooted here follows at most R in all)."""
        r = event.rays.ray[rows]
        k = self.run[r] + extra
        return self.anchor[r] & (k >= 1) & (k <= self.k_max) & (self.refl[r] <= self.r_max)

    def claims(self, event, rows) -> np.ndarray:
        """Interface hits ``rows`` whose runs the chains own from here (split trees and reflection
        splits must not count them)."""
        return self.owns(event, rows, extra=1)

    def share_walk_hits(self, event, rec, rec_w):
        drop = np.flatnonzero(self.owns(event, rec))
        if len(drop) == 0:
            return rec, rec_w
        return keep_walk_share(event, rec, rec_w, drop, np.zeros(len(drop)))

    def _connect_vertices(self, event, rows):
        """One vertex connection A -> P from each scatter vertex ``rows`` (rows of the event)."""
        if len(rows) == 0:
            return
        rays, hit, spec = event.rays, event.hits, event.spec
        r = rays.ray[rows]
        have = self.count[r] > 0
        rows, r = rows[have], r[have]
        if len(rows) == 0:
            return
        u = (self.u_choice[r] + _GOLDEN * rays.depth[rows]) % 1.0
        pick = self.first[r] + np.minimum((u * self.count[r]).astype(np.int64), self.count[r] - 1)
        e = self.ends
        a = take_rows(hit.point_mm, rows)
        n_a = take_rows(hit.facing_normal, rows)
        p = e.point[pick]
        n_p = e.normal[pick]
        vec = p - a
        d2 = np.einsum("ij,ij->i", vec, vec)
        dist = np.sqrt(d2)
        w_ap = vec / np.where(dist > 0, dist, 1.0)[:, None]
        cos_a = _dot(w_ap, n_a)
        cos_p = -_dot(w_ap, n_p)
        g = np.flatnonzero((cos_a > 0) & (cos_p > 0) & (dist > 4.0 * spec.eps))
        if len(g) == 0:
            return
        origin = np.ascontiguousarray(a[g] + 2.0 * spec.eps * n_a[g])
        target = p[g] + 2.0 * spec.eps * n_p[g]
        seg = target - origin
        seg_len = np.linalg.norm(seg, axis=1)
        blocked = np.asarray(event.scene.isect.occluded(origin, np.ascontiguousarray(seg / seg_len[:, None]),
                                                        np.ascontiguousarray(seg_len * (1.0 - 1e-9))))
        event.shadow_rays += len(g)
        g = g[~blocked]
        if len(g) == 0:
            return
        i = rows[g]
        k = pick[g]
        mat_a = spec.part_material[hit.part[i].astype(np.int64)]
        f_a, pdf_a = _brdf(spec, mat_a, n_a[g], -take_rows(rays.direction, i), w_ap[g], with_pdf=True)
        f_p, pdf_p = _brdf(spec, e.material[k], n_p[g], -w_ap[g], e.omega[k], with_pdf=True)
        mis = self._eye_weight(k, pdf_a * cos_p[g] / d2[g] * pdf_p)
        value = (rays.weight_w[i] * f_a * cos_a[g] * cos_p[g] / d2[g] * f_p * e.beta[k] * self.count[r[g]] * mis)
        keep = value > 0
        i, k, value = i[keep], k[keep], value[keep]
        if len(i) == 0:
            return
        self._tally(event.tallies, event.rows, event.records, rays.ray[i], hit.part[i].astype(np.int64), k, value,
                    rays.history[i] if event.settings.record_paths else None, rays.depth[i],
                    (rays.path_key[i], hit.part[i].astype(np.int64) * 4 + EVENT_SCATTER)
                    if event.settings.record_paths else None)

    # ------------------------------------------------------------------ tallies

    def _tally(self, tallies, rows, records, ray, exchange_part, k, value, history, depth, prefix):
        """Add ``value`` to the detector of end points ``k`` (ray ``ray``), take it from the NEE
        exchange of ``exchange_part``, and record it at the eye's detector point."""
        e = self.ends
        j_of = e.detector[k]
        for j in distinct(j_of):
            m = np.flatnonzero(j_of == j)
            tallies.add(rows.detector_nee + int(j), ray[m], value[m])
            tallies.subtract(rows.nee_exchange + exchange_part[m], ray[m], value[m])
            keys = events = None
            n_before = np.zeros(len(m), np.int64) if depth is None else np.asarray(depth)[m]
            total_depth = n_before + 1 + e.k[k[m]] + (0 if prefix is None else 1)
            if records.record_paths:
                if prefix is None:
                    h = np.zeros(len(m), np.uint64)
                else:
                    h = mix_key(prefix[0][m], prefix[1][m])
                h = mix_key(h, e.part[k[m]] * 4 + EVENT_SCATTER)
                events = _path_events(history, m, n_before, prefix, e, k[m], self.path_depth)
                for step in range(e.codes.shape[1]):
                    c = e.codes[k[m], step]
                    on = c >= 0
                    h = np.where(on, mix_key(h, np.where(on, c, 0)), h)
                keys = mix_key(h, records.detector_parts[int(j)] * 4 + EVENT_DETECTOR)
            records.add(int(j), ray[m], e.z[k[m]], value[m], keys, events, total_depth)


def _path_events(history, m, n_before, prefix, e, k, width):
    """Event codes of the recorded paths: the ray's history, A (vertex connections), P, the interfaces."""
    ev = np.full((len(m), width), -1, dtype=np.int16) if history is None else history[m].copy()
    rows = np.arange(len(m))
    pos = n_before.copy()
    if prefix is not None:
        at = pos < width
        ev[rows[at], pos[at]] = prefix[1][m][at]
        pos = pos + 1
    at = pos < width
    ev[rows[at], pos[at]] = e.part[k][at] * 4 + EVENT_SCATTER
    pos = pos + 1
    for step in range(e.codes.shape[1]):
        c = e.codes[k, step]
        at = (c >= 0) & (pos + step < width)
        ev[rows[at], (pos + step)[at]] = c[at]
    return ev


def _forward_codes(codes, k):
    """Interface codes met by eye chains (eye order, -1 padded) in the forward light's order: row i's
    first k_i codes reversed (per distinct k, a reversed slice)."""
    k = np.asarray(k, dtype=np.int64)
    out = np.full(codes.shape, -1, dtype=codes.dtype)
    for kk in distinct(k):
        if kk > 0:
            rows = np.flatnonzero(k == kk)
            out[rows, :kk] = codes[rows, kk - 1::-1]
    return out
