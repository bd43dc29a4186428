"""The precision stop rule (docs/decisions.md, "The precision stop"): what a target is, when a run of
rounds may stop, how many rays the next round gets, and the reliability of an error estimate from
per-chunk sums. The rounds themselves are traced by ``straylight.analyses.precision`` (PST, trace) and
``straylight.thermal.run``; the rule sits below both.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from straylight.rng import CHUNK_RAYS

DEFAULT_FIRST_RAYS = 20_000
DEFAULT_MAX_RAYS = 50_000_000
DEFAULT_MAX_VOV = 0.1
DEFAULT_MIN_CHUNKS = 40
DEFAULT_CONFIRM_GROWTH = 0.5
DEFAULT_MAX_JUMP = 2.0
DEFAULT_MAX_CHUNK_SHARE = 0.25
MAX_GROWTH = 4.0  # a round adds at most 4x the rays traced so far
SAFETY = 1.15  # aim 15 % beyond the rays the 1/sqrt(N) law predicts
#: an error this far below the target (a share of it) meets it whatever the VOV and chunk share (Precision.meets)
FAR_BELOW = 1e-3
#: the per-ray spread sum (x - mean)^2, as a share of sum x^2, below which the chunk sums do not resolve it (their
#: differences lose ~16 digits): :func:`reliability` then reports the bound as the error and no tail
ROUND_OFF_SPREAD = 1e-12
#: two looks this close (relative) are steady whatever their error bars: the round-off of sums over 1e5-1e7 rays
#: (an estimate that is nearly all a computed part, e.g. the direct light of straylight.engine.direct_area on
#: axis, has error bars of 1e-10 and below, under the sums' own round-off)
STEADY_ROUND_OFF = 1e-9


@dataclass(frozen=True)
class Precision:
    """What to trace to: relative standard error ``target_rel_error`` (e.g. 0.02), with caps."""

    target_rel_error: float
    max_rays: int = DEFAULT_MAX_RAYS
    max_seconds: float = math.inf
    first_rays: int = DEFAULT_FIRST_RAYS
    max_vov: float = DEFAULT_MAX_VOV
    min_chunks: int = DEFAULT_MIN_CHUNKS
    confirm_growth: float = DEFAULT_CONFIRM_GROWTH
    max_jump: float = DEFAULT_MAX_JUMP
    max_chunk_share: float = DEFAULT_MAX_CHUNK_SHARE

    def __post_init__(self):
        if not (0 < float(self.target_rel_error) < 1):
            raise ValueError(f"target relative error must be in (0, 1), got {self.target_rel_error!r}")
        if int(self.max_rays) < CHUNK_RAYS:
            raise ValueError(f"max rays must be >= {CHUNK_RAYS}, got {self.max_rays!r}")
        if not float(self.max_seconds) > 0:
            raise ValueError(f"max seconds must be > 0, got {self.max_seconds!r}")
        if int(self.first_rays) < CHUNK_RAYS:
            raise ValueError(f"first round must have >= {CHUNK_RAYS} rays, got {self.first_rays!r}")
        if not float(self.max_vov) > 0:
            raise ValueError(f"max VOV must be > 0, got {self.max_vov!r}")
        if int(self.min_chunks) < 2:
            raise ValueError(f"min chunks must be >= 2, got {self.min_chunks!r}")
        if not float(self.confirm_growth) >= 0 or not float(self.max_jump) > 0:
            raise ValueError("confirm growth must be >= 0 and max jump > 0")
        if not 0 < float(self.max_chunk_share) <= 1:
            raise ValueError(f"max chunk share must be in (0, 1], got {self.max_chunk_share!r}")

    def meets(self, look: "Look") -> bool:
        """One look meets the target: error, VOV, enough chunks, no chunk dominating the variance. An error
        :data:`FAR_BELOW` of the target meets it whatever its VOV and chunk share say (an error bar a thousand
        times too small would still meet it: a computed part carries the estimate, e.g. the direct light of
        straylight.engine.direct_area, and the rare scatter around it is a part in 1e6 of it)."""
        if not (math.isfinite(look.rel_error) and tail_aware(look.rel_error, look.vov) <= self.target_rel_error
                and look.chunks >= self.min_chunks):
            return False
        far_below = tail_aware(look.rel_error, look.vov) <= FAR_BELOW * self.target_rel_error
        return far_below or (look.vov <= self.max_vov and look.max_chunk_share <= self.max_chunk_share)

    def stops(self, looks: list) -> bool:
        """The target holds on the last two looks, the later with ``confirm_growth`` more rays, and the
        estimate moved by at most ``max_jump`` of the later standard error between them (or by at most
        :data:`STEADY_ROUND_OFF` of it: round-off)."""
        if len(looks) < 2 or not (self.meets(looks[-1]) and self.meets(looks[-2])):
            return False
        a, b = looks[-2], looks[-1]
        grown = b.n_rays >= (1.0 + self.confirm_growth) * a.n_rays - 0.5
        steady = abs(b.estimate - a.estimate) <= max(self.max_jump * tail_aware(b.rel_error, b.vov),
                                                     STEADY_ROUND_OFF) * abs(b.estimate)
        return grown and steady


@dataclass(frozen=True)
class Look:
    """The decisive detector's numbers after one round: what the stop rule sees."""

    n_rays: int
    estimate: float
    rel_error: float
    vov: float
    max_chunk_share: float
    chunks: int


@dataclass(frozen=True)
class Reliability:
    """How far the error estimate of one tally can be trusted (see the module docstring)."""

    rel_error: float
    vov: float
    rel_error_of_error: float
    max_chunk_share: float  # largest 1000-ray chunk's share of sum (x - m)^2: a heavy ray shows here
    chunks: int

    def to_dict(self) -> dict:
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in self.__dict__.items()}


def reliability(chunk_s1, chunk_s2, n_rays: int, chunk_rays=None) -> Reliability:
    """Relative error, VOV and the largest chunk's share from per-chunk sums of per-ray values x.

    chunk_s1, chunk_s2 : (K,) sums of x and x^2 per chunk (x: a ray's contribution, the estimate is
    sum x); chunk_rays : (K,) rays per chunk (default: all CHUNK_RAYS but the last).
    """
    s1 = np.asarray(chunk_s1, dtype=np.float64)
    s2 = np.asarray(chunk_s2, dtype=np.float64)
    n = int(n_rays)
    k = len(s1)
    if chunk_rays is None:
        chunk_rays = np.full(k, CHUNK_RAYS, dtype=np.float64)
        if k:
            chunk_rays[-1] = n - CHUNK_RAYS * (k - 1)
    c_n = np.asarray(chunk_rays, dtype=np.float64)
    total = float(s1.sum())
    mean = total / n  # mean contribution per ray
    c = s2 - 2.0 * mean * s1 + c_n * mean * mean  # sum over chunk of (x - mean)^2
    sum_c = float(c.sum())
    if n < 2 or total == 0:
        return Reliability(math.nan, math.nan, math.nan, math.nan, k)
    floor = ROUND_OFF_SPREAD * float(np.abs(s2).sum())
    if sum_c <= floor:
        # the rays' values are alike to ~1e-6 of their size (a computed part carries the estimate): their spread
        # is below what these sums resolve, so the error bar is that bound, and no ray can be a heavy tail
        return Reliability(abs(math.sqrt(floor * n / (n - 1)) / total), 0.0, 0.0, 1.0 / max(k, 1), k)
    stderr = math.sqrt(sum_c * n / (n - 1))
    expected = c_n * sum_c / n
    var_sum = float(np.sum((c - expected) ** 2)) * k / max(k - 1, 1)
    vov = var_sum / sum_c**2
    return Reliability(abs(stderr / total), vov, 0.5 * math.sqrt(vov), float(c.max() / sum_c), k)


def tail_aware(rel_error: float, vov: float) -> float:
    """The reported relative error of a precision run: ``rel_error (1 + sqrt(VOV))`` (module docstring)."""
    if not (math.isfinite(rel_error) and math.isfinite(vov)):
        return rel_error
    return rel_error * (1.0 + math.sqrt(max(vov, 0.0)))


def _chunk_rays(n: int) -> int:
    return int(-(-int(n) // CHUNK_RAYS) * CHUNK_RAYS)


def next_round_rays(looks: list, precision: Precision, elapsed_s: float = 0.0) -> int:
    """Rays of the next round: what the 1/sqrt(N) law asks for (at least the minimum sample), at least a
    quarter more (a VOV still too high needs more rays even at the target), ``confirm_growth`` more
    when the last look met the target (the confirming look), at most MAX_GROWTH x what is done; within
    the caps."""
    last = looks[-1]
    n_done, err = last.n_rays, last.rel_error
    want = n_done * (err / precision.target_rel_error) ** 2 * SAFETY if math.isfinite(err) else MAX_GROWTH * n_done
    want = max(want, precision.min_chunks * CHUNK_RAYS)
    least = precision.confirm_growth if precision.meets(last) else 0.25
    add = min(max(want - n_done, least * n_done), MAX_GROWTH * n_done, precision.max_rays - n_done)
    per_ray = elapsed_s / n_done if n_done else 0.0
    if math.isfinite(precision.max_seconds) and per_ray > 0:
        add = min(add, max((precision.max_seconds - elapsed_s) / per_ray, CHUNK_RAYS))
    n = _chunk_rays(max(add, CHUNK_RAYS))
    return min(n, precision.max_rays - n_done) if precision.max_rays - n_done >= CHUNK_RAYS else n
