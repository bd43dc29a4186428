"""Entrance sampling: the source's rays start where light reaches the detectors, by importance.

A collimated beam over an aperture reaches a small detector behind a lens only from a few entrance
points: the lens's own two-reflection ghost of the direct beam (a deterministic path from the entrance
point: ~3e-4 of the aperture at 10 deg on the guide scope), the part of the dew shield whose glossy
reflection the lens's ghost then focuses onto the sensor (30 deg), the vane spot the lens focuses the
beam onto. A uniform source finds them by chance; this strategy draws the entrance points from a
learnt density instead, each ray weighted by the ratio of the densities (importance sampling).

**The density.** Every source maps its first two emission uniforms (u1, u2) = the source's own
``u[:, 0:2]`` (a disk: radius sqrt(u1), azimuth 2 pi u2) to where (or which way) a ray leaves; the
rays of the walk have a uniform density on that unit square. Here the square is cut into G x G cells
and a ray first picks cell c with probability P_c, then a uniform point in it: the density on the
square is p(u) = G^2 P_c, and the ray starts with weight w0 / p(u) (w0 = total power / n_rays), so
E[w g] = integral of w0 g du for any path contribution g: unbiased for any table with P_c > 0 everywhere
(Kahn and Marshall 1953; Veach 1997 eq. 2.7). The cell is picked with u1 itself (inverse CDF over
the flattened cells) and the residual of that pick, uniform on [0, 1) and independent of the cell,
becomes the position in the cell along u1: the ray keeps its own 5 emission uniforms and draws
nothing more, so results stay identical for any batch, thread or worker split.

**The table** is learnt before the run by a pilot trace of :data:`PILOT_RAYS` rays with the same
estimators except reverse chains in its first stage (whose source connections do not depend on the entrance
point: on the guide scope their cosine-drawn chains put single heavy values on random cells; without them the
walk counts that family itself, from the entrance points that light it; the rest runs them: "The walk's
share" below), and with at most
:data:`PILOT_NEE_SPLIT` NEE samples at a glint (the tables stay as good for less CPU;
:func:`pilot_estimator`) (own streams: chunks from :data:`PILOT_CHUNK_OFFSET` on, so the table does not
depend on the run's own draws, and depends only on scene, sources, options and seed, like the vertex
tables): each pilot ray's total detector contribution x (its path records summed) goes to its cell; with
m_c = mean of x^2 over the cell's pilot rays, smoothed over the 3 x 3 neighbouring cells (azimuth
periodic), the variance-optimal choice for piecewise-constant importance sampling is P_c proportional
to sqrt(m_c) (the density proportional to the root mean square of the contribution); a defensive
fraction :data:`DEFENSIVE` of uniform keeps every cell drawn (Hesterberg 1995), so a path the pilot
never saw keeps at least that share of its rays (its variance grows at most 1 / DEFENSIVE). A pilot
that reaches no detector gives no table (uniform rays, as without the strategy).

**A pilot stops when it has seen enough.** It traces :data:`PILOT_FIRST_RAYS` rays first and the rest of
:data:`PILOT_RAYS` only when their contributions' effective sample size (sum x)^2 / sum x^2 is below
:data:`PILOT_ENOUGH_ESS`: a bright point (the direct image near the axis, where most rays reach the sensor with
alike weights) has learnt its table by then, and the rest would cost a third of a 0 deg point's trace;
where a few rays carry the light (off axis, behind the lens) the whole pilot runs. The first stage is
the whole pilot's first rays (the same streams), so the table depends only on scene, sources, options and
seed, as before.

**The rest of the pilot draws from the first stage's table** when at least :data:`PILOT_GUIDE_HITS` of the
first stage's rays saw light (population Monte Carlo, Cappe et al. 2004; the cross-entropy method,
Rubinstein 1999): a thin entrance region (the ghost of the direct beam at 15 deg on the guide scope: 1.6e-4
of the beam, ~5 uniform pilot rays in it) is then met by hundreds of pilot rays, and its fine cells get
their share instead of the defensive floor. A guided ray is uniform inside its cell, so it still
measures its cell's mean: with x its contribution and p(u) the first table's density, x p(u) is what it
would have carried from a uniform start, and each ray enters its cells' means with the weight
rho = 1 / p(u) (self-normalised: m_c = sum rho (x p)^2 / sum rho, the coarse scales' means stay means over
the uniform measure). Below that many lit rays the rest stays uniform: a table from a handful of rays (the
guide scope at 60 deg: 44-48 lit rays in 1e4, effective sample size 1.1-1.6) would draw the rest onto its
own few cells, and the run's other families would lose the coarse scales' mass (measured: at 60 deg 2 runs
in 6 went from 1.6 % to 5-20 % at 1e5 rays). At 45 deg (528-573 lit rays, effective sample size 4-7), guided
with 300 instead of 1000, whole ``pst`` commands to 2 % over seeds 1-8 needed 1.11e5 rays on average
(at most 1.40e5) against 1.71e5 (at most 3.05e5) uniform (docs/engine.md, "Entrance points by importance"). Over 6 seeds at 1e5 rays, CPU s x rel^2 (%^2) median
(mean) uniform -> guided: 5 deg 13.7 (14.3) -> 12.6 (11.8); 10 deg 30.0 (31.2) -> 28.6 (30.2); 15 deg 164
(912) -> 48 (83); 20 deg 19.2 (20.7) -> 19.7 (22.0); 30 deg 25.3 (31.3) -> 22.6 (29.9). Ending the guided
rest early, once its rays' contributions have a large enough effective sample size, was tried and not kept
(a walk call costs ~0.1 CPU s of its own; 15 deg's thin region does not show in that statistic;
docs/engine.md, "The pilot's cost").

**The walk's share.** Where the run traces eye chains with a table (straylight.engine.reverse_chain), the run's
walk does not count what a pilot without them sees: the chains count the family "source -> P -> interfaces ->
detector" (P a plain scatterer the beam lights), the walk's own paths of it are dropped, and its split trees keep
only their balance share p_walk / (p_walk + p_eye), small where the chains draw densely. A table learnt from the
family in full puts the entrance points where the chains already do well. So the eye pilot runs after the first
stage (weighing its chains against the power that stage detected), the rest of the pilot runs the chains with the
run's eye table, their source connections not counted (the same for any entrance point: ``EyeTable.
source_connections``), and the table is learnt from the rest and the first stage's records outside the family
(``chain_family``, from the records' events: :data:`PILOT_PATH_DEPTH`); the first stage's table, which guides the
rest, keeps them all. Only where the rest is guided: at 60 deg on the guide scope (44-48 lit rays in the first
stage, the rest uniform) a table from a uniform rest with the chains alone (the first stage dropped) left single
runs at 10-34 % (1e5 rays, 16 seeds), and with the first stage's other records pooled two at 13-15 %
(median 0.81 % against 0.74 %): the pilot there is as before. Guide scope, 32 seeds of 1e5 rays each, relative
error median (root mean square), before -> after: 45 deg 1.21 (1.25) -> 1.04 (1.10) %, 30 deg 1.05 (1.77) -> 0.97
(1.39) %; learnt from the rest alone (the first stage dropped): 45 deg 1.03 (1.09) %, but 30 deg 1.13 (1.63) %, the
lens cell's glints (walk-owned, seen in the first stage's uniform rays) losing their cells (docs/engine.md, "The
walk's share").

**The finest grid** (:data:`GRID` = 256 cells per side, with the 64, 16 and 4 grids of :data:`SCALES`)
resolves the ghost of the direct beam, narrower than a 64-grid cell (guide scope, 6 seeds at 1e5 rays,
CPU s x rel^2 median with the 64 grid -> 256: 5 deg 13.9 -> 5.4, 10 deg 16.8 -> 5.2, 15 deg 67 -> 24,
20 deg 19.7 -> 4.3, 30 deg 21.7 -> 9.4, 45 deg 28.9 -> 22.0, 60 deg 5.4 -> 3.1; docs/engine.md).

**The scales' weights** (:data:`SCALE_WEIGHTS`: 1, 1, 0.2, 0.1 for the 256, 64, 16 and 4 grids, normalised;
equal weights before): at equal weights the two coarse grids held half of the non-defensive draws, spread over
cells 16-4096x the fine ones around what the pilot saw. At 45 deg on the guide scope the light is the dew
shield's glossy patch that the lens's ghost carries to the sensor (~1 % of the beam); 60 % of the rays' glossy first
vertices fell near it and a few per cent of the rays carried half the light. Whole ``pst`` commands to 2 %, seeds
1-8, median CPU s equal -> these weights: 45 deg 3.64 -> 3.04, 30 deg 3.53 -> 3.30, 60 deg 3.00 -> 2.25, 5-20 deg
the same or less; the imported Cooke triplet's 20 deg point (a heavy-tailed TIR ghost) no better or worse over
seeds 0-6. The defensive share stays: with it at 0.1, 30 deg had 6 heavy runs in 8 (docs/engine.md, "The
table's scale weights").

**The ledger.** The start weights no longer add up to the emitted power exactly: each ray's
w0 - w (expectation zero) is booked to the ``escaped`` row, which keeps escaped an unbiased estimate
of the escaped power and the ledger exact (emitted = detected + absorbed + escaped to round-off).

The vertex strategies' balance weights keep the uniform source's density p_F of the first vertex: the
weights of the walk and of the area strategy still add to one for every path, so the sum stays
unbiased (only the split between the two strategies is no longer the balance optimum).
"""
from __future__ import annotations

import weakref
from dataclasses import dataclass, replace

import numpy as np

from materials.sampling import lazy_njit
from straylight.engine.draws import EMISSION_COLUMNS
from straylight.rng import CHUNK_RAYS, n_chunks

#: cells per side of the table over the source's first two uniforms
GRID = 256
#: the grids (cells per side, dividing GRID) whose tables are mixed
SCALES = (256, 64, 16, 4)
#: the mixture's weights of the SCALES' tables (normalised): the coarse grids are a fallback for paths the pilot
#: saw a few times, and at equal weights they put half of the non-defensive draws over cells 16-4096x the fine
#: ones (guide scope, 8 seeds, whole ``pst`` commands to 2 %: 45 deg median 3.64 -> 3.04 CPU s; module doc)
SCALE_WEIGHTS = (1.0, 1.0, 0.2, 0.1)
#: rays of the pilot trace that learns the table
PILOT_RAYS = 30_000
#: rays of the pilot's first stage; the rest of PILOT_RAYS only below PILOT_ENOUGH_ESS (module doc)
PILOT_FIRST_RAYS = 10_000
#: rays of the first stage with a detector contribution that let the rest draw from its table (module doc)
PILOT_GUIDE_HITS = 300
#: effective sample size of the first stage's contributions that ends the pilot (~ half the 64 x 64 scale's
#: cells: an average such cell seen by one ray's worth of light at least)
PILOT_ENOUGH_ESS = 2_000.0
#: most NEE samples at a glint in the pilot (the run's nee_split when lower): the default set's 64 cost the
#: pilot a fifth of its CPU at 5-20 deg on the guide scope for tables no better (docs/engine.md, "The pilot's cost")
PILOT_NEE_SPLIT = 8
#: events per path record in the pilot where the run traces eye chains (what
#: straylight.engine.reverse_chain.chain_family reads to leave their family out of the first stage)
PILOT_PATH_DEPTH = 8
#: share of the draws left uniform over the square (defensive mixture)
DEFENSIVE = 0.25
#: the pilot's chunk streams start here (never reached by a trace's own ray ids)
PILOT_CHUNK_OFFSET = 1 << 40


@dataclass(frozen=True, eq=False)
class EntranceTable:
    """Cell probabilities ``prob`` (G*G, row-major: u1 cell, then u2 cell), their cumulative sums
    ``cdf`` and the pilot's size, for :func:`warp`."""

    grid: int
    prob: np.ndarray
    cdf: np.ndarray
    pilot_rays: int
    pilot_hits: int  # pilot rays with a detector contribution


def _smoothed_root(n_c: np.ndarray, s2: np.ndarray) -> np.ndarray:
    """sqrt of the mean x^2 per cell over its 3 x 3 neighbourhood (axis 0 clamped, axis 1 periodic)."""
    g = n_c.shape[0]
    pad_n = np.pad(n_c, ((1, 1), (0, 0)), mode="constant")
    pad_s = np.pad(s2, ((1, 1), (0, 0)), mode="constant")
    box_n = sum(np.roll(pad_n[a:a + g], b, axis=1) for a in range(3) for b in (-1, 0, 1))
    box_s = sum(np.roll(pad_s[a:a + g], b, axis=1) for a in range(3) for b in (-1, 0, 1))
    return np.sqrt(np.where(box_n > 0, box_s / np.maximum(box_n, 1.0), 0.0))


def _scale_tables(u: np.ndarray, x: np.ndarray, g: int, scales, rho: np.ndarray | None = None) -> np.ndarray:
    """(len(scales), G*G): per scale s, the normalised sqrt of the smoothed mean x^2 on s x s cells,
    spread evenly over the G x G cells each covers (zeros where no pilot ray contributed). ``rho``:
    the rays' weights 1 / p(u) when they were drawn with density p (self-normalised means; None: 1)."""
    i = np.minimum((u[:, 0] * g).astype(np.int64), g - 1)
    j = np.minimum((u[:, 1] * g).astype(np.int64), g - 1)
    cell = i * g + j
    if rho is None:
        n_c = np.bincount(cell, minlength=g * g).reshape(g, g).astype(np.float64)
        s2 = np.bincount(cell, weights=x * x, minlength=g * g).reshape(g, g)
    else:
        n_c = np.bincount(cell, weights=rho, minlength=g * g).reshape(g, g).astype(np.float64)
        s2 = np.bincount(cell, weights=rho * x * x, minlength=g * g).reshape(g, g)
    out = np.zeros((len(scales), g * g))
    for k, s in enumerate(scales):
        b = g // int(s)
        root = _smoothed_root(n_c.reshape(s, b, s, b).sum(axis=(1, 3)), s2.reshape(s, b, s, b).sum(axis=(1, 3)))
        if root.sum() > 0:
            out[k] = (np.repeat(np.repeat(root / root.sum(), b, axis=0), b, axis=1) / (b * b)).ravel()
    return out


def table_from_contributions(u: np.ndarray, x: np.ndarray, grid: int = GRID, defensive: float = DEFENSIVE,
                             scales: tuple = SCALES, rho: np.ndarray | None = None,
                             scale_weights: tuple | None = None) -> EntranceTable | None:
    """The table from pilot rays' first two source uniforms ``u`` (n, 2) and contributions ``x`` (n,):
    P_c = defensive / G^2 + (1 - defensive) sum_s a_s q_s(c), where q_s is the normalised sqrt of the
    smoothed mean x^2 on a grid of s x s cells (s in ``scales``, spread evenly over the G x G cells
    each covers) and a_s the normalised ``scale_weights`` (default :data:`SCALE_WEIGHTS` for
    :data:`SCALES`, equal for other scales). The fine grids resolve a small deterministic region (the ghost
    of the direct beam) and the glossy patch whose scatter a ghost carries to the sensor; the coarse ones keep
    mass over the whole region where a rare path happens when the pilot saw it only a few times. As a
    mixture, the table's variance is at most 1 / a_s times that of scale s alone. ``rho`` (n,): each ray's
    1 / p(u) when the pilot drew it from a density p (a table of its earlier stage; the means per cell are
    then self-normalised, sum rho x^2 / sum rho, estimates of the same uniform-measure means)."""
    g = int(grid)
    u = np.asarray(u, dtype=np.float64)
    x = np.asarray(x, dtype=np.float64)
    hits = int(np.count_nonzero(x))
    if hits == 0:
        return None
    if scale_weights is None:
        scale_weights = SCALE_WEIGHTS if tuple(scales) == SCALES else (1.0,) * len(scales)
    a = np.asarray(scale_weights, dtype=np.float64)
    if a.shape != (len(scales),) or np.any(a < 0) or a.sum() <= 0:
        raise ValueError(f"scale_weights must be {len(scales)} non-negative numbers, not all 0; got {scale_weights}")
    tables = _scale_tables(u, x, g, scales, None if rho is None else np.asarray(rho, dtype=np.float64))
    q = (a / a.sum()) @ tables
    prob, cdf = _normalised(defensive / (g * g) + (1.0 - defensive) * q)
    return EntranceTable(grid=g, prob=prob, cdf=cdf, pilot_rays=len(x), pilot_hits=hits)


def _normalised(prob: np.ndarray) -> tuple:
    """The cell probabilities ``prob`` scaled to sum 1 and their cumulative sums (the last exactly 1)."""
    prob = prob / prob.sum()
    cdf = np.cumsum(prob)
    cdf[-1] = 1.0
    return prob, cdf


def with_component(table: EntranceTable, u: np.ndarray, share: float) -> EntranceTable:
    """``table`` mixed with the histogram of the source uniforms ``u`` (m, 2) on its grid, at ``share``: P_c =
    (1 - share) P_c + share n_c / m (a mixture keeps every cell the table had; unbiased for any share, as any
    table is). ``table`` itself where ``u`` is empty."""
    if len(u) == 0 or share <= 0:
        return table
    g = int(table.grid)
    i = np.minimum((u[:, 0] * g).astype(np.int64), g - 1)
    j = np.minimum((u[:, 1] * g).astype(np.int64), g - 1)
    counts = np.bincount(i * g + j, minlength=g * g).astype(np.float64)
    prob, cdf = _normalised((1.0 - share) * table.prob + share * counts / counts.sum())
    return replace(table, prob=prob, cdf=cdf)


def warp(table: EntranceTable, u: np.ndarray) -> np.ndarray:
    """Move the source uniforms ``u[:, 0], u[:, 1]`` (in place) to the table's density; returns each
    ray's weight factor 1 / p(u) = 1 / (G^2 P_c). u1 picks the cell by inverse CDF, its residual
    (u1 - CDF_{c-1}) / P_c is the position in the cell along u1, u2 the position along u2. One
    compiled pass (:func:`_warp_loop`) over :func:`warp_numpy`'s operations in its order (the same
    bits); the cell is found from a guide table of the CDF (:func:`_guide`) and a short scan, the
    cell ``np.searchsorted(cdf, u1, side="right")`` names (the first whose CDF exceeds u1)."""
    n = len(u)
    factor = np.empty(n)
    if n == 0:
        return factor
    uc = np.ascontiguousarray(u, dtype=np.float64)
    lazy_njit(_warp_loop, "numpy")(table.cdf, table.prob, _guide(table), int(table.grid), float(np.nextafter(1.0, 0.0)),
                                   uc, factor)
    if uc is not u:
        u[:, :2] = uc[:, :2]
    return factor


def warp_numpy(table: EntranceTable, u: np.ndarray) -> np.ndarray:
    """:func:`warp` in vectorised numpy (the reference it is tested against)."""
    g = table.grid
    a = u[:, 0]
    c = np.minimum(np.searchsorted(table.cdf, a, side="right"), g * g - 1)
    lo = np.where(c > 0, table.cdf[np.maximum(c - 1, 0)], 0.0)
    p = table.prob[c]
    frac = np.clip((a - lo) / p, 0.0, np.nextafter(1.0, 0.0))
    i, j = np.divmod(c, g)
    u[:, 0] = (i + frac) / g
    u[:, 1] = (j + u[:, 1]) / g
    return 1.0 / (g * g * p)


_GUIDES: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def _guide(table: EntranceTable) -> np.ndarray:
    """Per bucket b of the unit interval cut in M = len(cdf) equal parts: the first cell whose CDF
    exceeds b / M (where a uniform of that bucket starts its scan; computed once per table)."""
    guide = _GUIDES.get(table)
    if guide is None:
        m = len(table.cdf)
        guide = _GUIDES[table] = np.searchsorted(table.cdf, np.arange(m) / m, side="right").astype(np.int64)
    return guide


def _warp_loop(cdf, prob, guide, g, frac_max, u, factor):
    """:func:`warp_numpy` row by row. The cell: from the guide's start, back while the CDF before it
    exceeds u1, on while its own does not (the first cell whose CDF exceeds u1, whatever the start:
    the guide only shortens the scan)."""
    m = len(cdf)
    top = g * g - 1
    for r in range(len(u)):
        a = u[r, 0]
        b = min(max(int(a * m), 0), m - 1)
        c = guide[b]
        while c > 0 and cdf[c - 1] > a:
            c -= 1
        while c < m and cdf[c] <= a:
            c += 1
        c = min(c, top)
        lo = cdf[c - 1] if c > 0 else 0.0
        p = prob[c]
        frac = (a - lo) / p  # np.clip's max then min (a NaN kept, ties to the bound)
        if not (frac != frac or frac > 0.0):
            frac = 0.0
        if not (frac != frac or frac < frac_max):
            frac = frac_max
        i = c // g
        j = c - i * g
        u[r, 0] = (i + frac) / g
        u[r, 1] = (j + u[r, 1]) / g
        factor[r] = 1.0 / (g * g * p)


def density(table: EntranceTable, u: np.ndarray) -> np.ndarray:
    """The table's density p(u) = G^2 P_c at the source uniforms ``u`` (n, 2) (the density the warped
    rays of :func:`warp` have there)."""
    g = table.grid
    cell = np.minimum((u[:, 0] * g).astype(np.int64), g - 1) * g + np.minimum((u[:, 1] * g).astype(np.int64), g - 1)
    return g * g * table.prob[cell]


def start_weights(spec, u, w0: float, tallies, rows):
    """Emission with the table: warp the source columns of the batch's emission uniforms ``u``
    (n, 5: source choice, then the source's four) in place and return the start weights (n,); each
    ray's w0 - w goes to the ``escaped`` row (expectation zero: the ledger stays exact)."""
    factor = warp(spec.entrance_table, u[:, 1:3])
    w = w0 * factor
    tallies.add(rows.escaped, np.arange(len(w), dtype=np.int64), w0 - w)
    return w


def effective_sample_size(x: np.ndarray) -> float:
    """(sum x)^2 / sum x^2 of contributions ``x`` (0 when none): how many rays' worth of light they hold."""
    s2 = float(np.dot(x, x))
    return float(x.sum()) ** 2 / s2 if s2 > 0 else 0.0


def applies(spec) -> bool:
    """Whether a table can be used: one source (the table is over its uniforms) and a detector."""
    return len(spec.sources) == 1 and len(spec.detector_parts) > 0


def _pilot_uniforms(spec, n: int) -> np.ndarray:
    """The pilot's emission uniforms (n, EMISSION_COLUMNS) of its first ``n`` rays, as the walk draws them."""
    from straylight.engine.kernel_sets import COMPILED

    u = np.empty((n, EMISSION_COLUMNS))
    COMPILED.draws(spec.seed, PILOT_CHUNK_OFFSET, PILOT_CHUNK_OFFSET + n_chunks(n)).fill(
        np.arange(n, dtype=np.int64), EMISSION_COLUMNS, u, CHUNK_RAYS)
    return u


def pilot_estimator(est):
    """The pilot's estimator options from the run's ``est``: the same, without entrance sampling (the
    pilot learns its table), reverse chains (build_table) and the computed direct light (``direct_area``: a
    share every ray carries alike, whatever its entrance point, would flatten the table; the pilot's walk
    counts that light where it enters), specular NEE's ghosts (they join the eye chains, which the run may turn off,
    straylight.engine.specular_nee ``ghosts_on``: the table is learnt as without them) and with at most
    :data:`PILOT_NEE_SPLIT` NEE samples at a glint."""
    return replace(est, entrance_sampling=False, reverse_chain=0, direct_area=False, lens_vertex=False,
                   specular_nee=min(int(est.specular_nee), 3), nee_split=min(int(est.nee_split), PILOT_NEE_SPLIT))


def build_table(spec, run_batch, intersector=None, n_rays: int = PILOT_RAYS, eye_table=None,
                chain_family=None) -> EntranceTable | None:
    """Learn the table from a pilot trace of ``n_rays`` rays with ``spec``'s estimators (own
    streams, path records for the per-ray contributions) in two stages: uniform rays first, the rest
    drawn from the first stage's table (module doc). ``run_batch(spec, first_chunk, stop_chunk,
    intersector)`` is the compiled walk (straylight.engine.walk.run_batch, passed in: the walk
    imports this module). ``eye_table``: None, or a callable called when the first stage is done, giving the
    eye table the run's chains will draw with (straylight.engine.reverse_chain.EyeTable; its pilot weighs the
    chains against the power that stage detected) or None when the run traces no eye chains with a table; with a
    table the rest runs with the eye chains as the run will, and the first stage's rays count only their records
    outside the chains' family (``chain_family(events)``: a mask of path records by their event codes,
    straylight.engine.reverse_chain.chain_family; module doc, "The walk's share")."""
    opt = spec.options
    # the first stage without the reverse chains: their source connections do not depend on the ray's entrance
    # point (each ray's eye chains are drawn on their own), so in a pilot they only add noise to the cells; the
    # walk's own paths of their family (kept without them) say which entrance points light the scatter points the
    # lens carries onto the sensor (the rest may run them without their source connections: _rest_of_pilot)
    depth = PILOT_PATH_DEPTH if eye_table is not None else 1  # the events chain_family reads
    pilot_opts = replace(opt, estimator=pilot_estimator(opt.estimator),
                         output=replace(opt.output, record_paths=True, path_depth=depth))
    n = int(n_rays)
    # the pilot has its own plan: the walk resolves it from pilot_opts (this strategy off, its table None)
    pilot = replace(spec, n_rays=n, options=pilot_opts, chunk_offset=PILOT_CHUNK_OFFSET, entrance_table=None,
                    strategies_on=None)
    first = n_chunks(min(PILOT_FIRST_RAYS, n))
    first_result = run_batch(pilot, 0, first, intersector)
    x = _contributions(first_result, n)
    u = _pilot_uniforms(spec, n)
    n1 = min(first * CHUNK_RAYS, n)
    if n1 >= n or effective_sample_size(x) >= PILOT_ENOUGH_ESS:
        return table_from_contributions(u[:n1, 1:3], x[:n1])
    if np.count_nonzero(x) < PILOT_GUIDE_HITS:  # too few rays saw light to guide by: the rest uniform
        x += _contributions(run_batch(pilot, first, n_chunks(n), intersector), n)
        return table_from_contributions(u[:, 1:3], x)
    rest, walk_share = _rest_of_pilot(pilot, opt, eye_table)
    # the rest draws its entrance points from the first stage's table: its contributions carry the
    # factor 1 / p(u); x p(u) is the uniform-measure contribution, 1 / p(u) the ray's weight in its cell
    first_table = table_from_contributions(u[:n1, 1:3], x[:n1])
    assert first_table is not None  # it has lit rays
    guided = replace(rest, options=replace(rest.options, estimator=replace(rest.options.estimator, entrance_sampling=True)),
                     entrance_table=first_table)
    x_rest = _contributions(run_batch(guided, first, n_chunks(n), intersector), n)
    rho = np.ones(n)
    drawn = u[n1:, 1:3].copy()
    rho[n1:] = warp(first_table, drawn)
    u[n1:, 1:3] = drawn
    if walk_share:  # the first stage counted the chains' family in full: its other records only (module doc)
        x = _contributions(first_result, n, _outside(chain_family)) if chain_family is not None else np.zeros(n)
    x += x_rest
    return table_from_contributions(u[:, 1:3], x / rho, rho=rho)


def _rest_of_pilot(pilot, opt, eye_table) -> tuple:
    """The spec the pilot's rest runs with, and whether it runs the eye chains: with the run's eye table
    (``eye_table()``, see :func:`build_table`) the rest traces the chains as the run will, so the walk's trees keep
    the share the balance heuristic leaves them against the chains, but the chains' source connections (the same
    for any entrance point) are not counted; otherwise ``pilot`` itself."""
    table = eye_table() if eye_table is not None else None
    if table is None or int(opt.estimator.reverse_chain) <= 0:
        return pilot, False
    est = replace(pilot.options.estimator, reverse_chain=opt.estimator.reverse_chain)
    return replace(pilot, options=replace(pilot.options, estimator=est),
                   eye_table=replace(table, source_connections=False)), True


def _contributions(res, n: int, keep=None) -> np.ndarray:
    """Each pilot ray's total detector contribution (n,) from a batch result's path records (``keep(paths)``: a
    mask of the records to count; None: all)."""
    x = np.zeros(n)
    paths = res.get("paths")
    if paths is not None:
        ray = np.asarray(paths["ray"], dtype=np.int64)
        power = np.asarray(paths["power_w"], dtype=np.float64)
        if keep is not None:
            m = np.asarray(keep(paths), dtype=bool)
            ray, power = ray[m], power[m]
        np.add.at(x, ray, power)
    return x


def _outside(chain_family):
    """``keep`` for :func:`_contributions`: the records outside the eye chains' family."""
    return lambda paths: ~np.asarray(chain_family(paths["events"]), dtype=bool)


class EntranceWeights:
    """The walk's emission hook (``emit_batch(..., on_uniforms=)``): warps the batch's uniforms and
    keeps the start weights in :attr:`weights`."""

    def __init__(self, spec, w0: float, tallies, rows):
        self.spec, self.w0, self.tallies, self.rows = spec, float(w0), tallies, rows
        self.weights = None

    def __call__(self, u):
        self.weights = start_weights(self.spec, u, self.w0, self.tallies, self.rows)
