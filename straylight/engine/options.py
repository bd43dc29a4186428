"""Stage 0, what the user asks for: :class:`TraceOptions` and :class:`TraceError`.

The options come in three groups, each validating its own fields: how the power is estimated
(:class:`EstimatorOptions`: never changes the expectation, only the variance), what is recorded
(:class:`OutputOptions`) and what light does (:class:`PhysicsOptions`: changes the answer).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np


class TraceError(ValueError):
    """A trace request that cannot run; the message names the parameter or part."""


#: the choices of ``EstimatorOptions.specular_nee_sequences`` (straylight.engine.specular_nee.candidate_sequences):
#: "all" every sequence of 1..``specular_nee`` interfaces; "mirrors" only the single reflections off a face
#: and (``specular_nee = 3``) the thick mirrors: enter a face, reflect inside off another, leave through the first
#: (``specular_nee = 4``, also the ghosts: enter a face, reflect inside off the other and back, leave through the other)
SPECULAR_NEE_SEQUENCES = ("all", "mirrors")


@dataclass(frozen=True)
class EstimatorOptions:
    """How the detectors' power is estimated (the variance-reduction strategies,
    straylight.engine.estimators; all off is the analog walk). Same expectation either way."""

    nee: bool = True
    nee_samples: int = 1
    nee_split: int = 1  # > nee_samples: heavy glossy vertices take up to this many NEE samples (straylight.engine.nee_split)
    rr_threshold: float = 1e-3
    target_parts: tuple = ()
    target_fraction: float = 0.5
    first_vertex_sampling: bool = False
    second_vertex_sampling: bool = False
    vertex_lobe_sampling: bool = False  # first-vertex sampling also joins x to the detector by the lobe's own draw
    second_vertex_lobe_sampling: bool = False  # second-vertex sampling also leaves B by the lobe's own draw
    reflection_split: bool = False  # interface reflections into a detector counted by expected value
    delta_chain: int = 0  # > 0: runs of up to this many interfaces into a detector followed by splitting
    delta_chain_reflections: int = 0  # > 0: of those, the runs with at most this many reflections (a ghost's order)
    tree_split: int = 1  # > 1: glossy vertices lit by the source send this many lobe draws into the split trees
    tree_ends: bool = False  # the beam's split trees' branch ends on glossy parts (after a reflection) take a lobe draw
    entrance_sampling: bool = False  # source rays start where a pilot saw light reach the detectors (by importance)
    reverse_chain: int = 0  # > 0: eye chains from the detectors through up to this many interfaces, joined to the walk
    specular_nee: int = 0  # > 0: scatter vertices joined to the detectors through up to this many (1-4) analytic interfaces
    specular_nee_sequences: str = "all"  # which: "all" of 1..specular_nee, or "mirrors" (single reflections, thick mirrors T R T)
    direct_area: bool = False  # the light one collimated beam puts straight on a flat mesh detector, by 2-D clipping
    lens_vertex: bool = False  # scatter points lit through a lens area-sampled and joined to the beam through it

    def __post_init__(self):
        if not (0.0 <= float(self.rr_threshold) < 1.0):
            raise TraceError(f"rr_threshold must be in [0, 1), got {self.rr_threshold}")
        if int(self.nee_samples) < 1:
            raise TraceError(f"nee_samples must be >= 1, got {self.nee_samples}")
        if not isinstance(self.nee_split, (int, np.integer)) or int(self.nee_split) < 1:
            raise TraceError(f"nee_split must be an integer >= 1 (most NEE samples at a split vertex), got {self.nee_split!r}")
        if not (0.0 < float(self.target_fraction) < 1.0):
            raise TraceError(f"target_fraction must be in (0, 1), got {self.target_fraction}")
        if isinstance(self.target_parts, str):
            object.__setattr__(self, "target_parts", (self.target_parts,))
        object.__setattr__(self, "target_parts", tuple(self.target_parts))
        if int(self.delta_chain) < 0:
            raise TraceError(f"delta_chain must be >= 0 (interfaces per split tree), got {self.delta_chain}")
        if not isinstance(self.tree_split, (int, np.integer)) or int(self.tree_split) < 1:
            raise TraceError(f"tree_split must be an integer >= 1 (lobe draws into the split trees), got {self.tree_split!r}")
        if not isinstance(self.tree_ends, (bool, np.bool_)):
            raise TraceError(f"tree_ends must be True or False (lobe draws at the split trees' branch ends), "
                             f"got {self.tree_ends!r}")
        if int(self.delta_chain_reflections) < 0:
            raise TraceError(f"delta_chain_reflections must be >= 0 (reflections per split-tree branch; 0: no limit), "
                             f"got {self.delta_chain_reflections}")
        if int(self.reverse_chain) < 0:
            raise TraceError(f"reverse_chain must be >= 0 (interfaces per eye chain), got {self.reverse_chain}")
        if not isinstance(self.specular_nee, (int, np.integer)) or not 0 <= int(self.specular_nee) <= 4:
            raise TraceError(f"specular_nee must be 0, 1, 2, 3 or 4 (interfaces per connection), got {self.specular_nee!r}")
        object.__setattr__(self, "specular_nee", int(self.specular_nee))  # True (the former switch) is 1
        if self.specular_nee_sequences not in SPECULAR_NEE_SEQUENCES:
            raise TraceError(f"specular_nee_sequences must be one of {', '.join(SPECULAR_NEE_SEQUENCES)}, "
                             f"got {self.specular_nee_sequences!r}")
        # the most reflections one of its sequences has: "mirrors" have one, and with 4 interfaces the ghosts two
        k = int(self.specular_nee)
        reflections = (2 if k >= 4 else min(k, 1)) if self.specular_nee_sequences == "mirrors" else k
        if 0 < int(self.delta_chain_reflections) < reflections:
            raise TraceError(f"specular_nee ({self.specular_nee}, sequences {self.specular_nee_sequences!r}) shares its "
                             f"paths with the split trees: it needs delta_chain_reflections 0 (no limit) or >= {reflections}")
        if int(self.delta_chain) > 0 and self.reflection_split:
            raise TraceError("delta_chain includes reflection_split (its one-reflection paths): turn one of them off")


@dataclass(frozen=True)
class OutputOptions:
    """What the trace records beside the detector totals."""

    record_paths: bool = False
    path_depth: int = 12
    map_bins: tuple = (64, 64)
    detector_sides: str = "both"  # "both": detectors count light from both sides; "front": the front only
    ray_log: int = 0  # > 0: every segment of the trace's first ray_log rays is logged (straylight.engine.ray_log)

    def __post_init__(self):
        if isinstance(self.ray_log, bool) or int(self.ray_log) != self.ray_log or int(self.ray_log) < 0:
            raise TraceError(f"ray_log must be an integer >= 0 (rays whose segments are logged), got {self.ray_log!r}")
        if self.detector_sides not in ("both", "front"):
            raise TraceError(f"detector_sides must be 'both' or 'front', got {self.detector_sides!r}")
        if len(tuple(self.map_bins)) != 2 or min(self.map_bins) < 1:
            raise TraceError(f"map_bins must be two positive integers, got {self.map_bins!r}")


@dataclass(frozen=True)
class PhysicsOptions:
    """What light does in the trace. ``mirror_reflectance`` is the reflectance of parts of role
    ``mirror`` (CONTRACTS §6.3: "a specular surface with the trace's mirror reflectance"); a mirror
    with its own reflectance is a surface part with a specular material."""

    max_events: int = 1000
    polarization: str = "u"
    scatter_polarization: str = "auto"  # "auto": scatter follows polarized light only; "on": always
    diffraction: str = "scene"  # "scene": parts marked diffraction = "edges" diffract (HURB); "off": none do
    hurb_gamma: float = 0.7978845608028654  # HURB uncertainty factor sqrt(2/pi) (straylight.engine.hurb)
    diffraction_band_wavelengths: float = 100.0  # rays passing an edge closer than this many wavelengths bend
    mirror_reflectance: float = 1.0

    def __post_init__(self):
        if int(self.max_events) < 1:
            raise TraceError(f"max_events must be >= 1, got {self.max_events}")
        if self.scatter_polarization not in ("auto", "on"):
            raise TraceError(f"scatter_polarization must be 'auto' or 'on', got {self.scatter_polarization!r}")
        if self.diffraction not in ("scene", "off"):
            raise TraceError(f"diffraction must be 'scene' or 'off', got {self.diffraction!r}")
        if not (float(self.hurb_gamma) > 0.0 and float(self.diffraction_band_wavelengths) > 0.0):
            raise TraceError("hurb_gamma and diffraction_band_wavelengths must be > 0")
        if not (0.0 <= float(self.mirror_reflectance) <= 1.0):
            raise TraceError(f"mirror_reflectance must be in [0, 1], got {self.mirror_reflectance}")


@dataclass(frozen=True)
class TraceOptions:
    """Options of :func:`straylight.trace.trace` (see docs/engine.md, "Options"): the three groups
    and ``batch_rays`` (rays per in-memory batch; never changes results)."""

    estimator: EstimatorOptions = field(default_factory=EstimatorOptions)
    output: OutputOptions = field(default_factory=OutputOptions)
    physics: PhysicsOptions = field(default_factory=PhysicsOptions)
    batch_rays: int | None = None  # None: straylight.engine.spec.AUTO_BATCH_RAYS

    def __post_init__(self):
        for name, kind in (("estimator", EstimatorOptions), ("output", OutputOptions), ("physics", PhysicsOptions)):
            if not isinstance(getattr(self, name), kind):
                raise TraceError(f"TraceOptions.{name} must be a {kind.__name__}, "
                                 f"got {type(getattr(self, name)).__name__}")
        if self.batch_rays is not None and int(self.batch_rays) < 1:
            raise TraceError(f"batch_rays must be >= 1, got {self.batch_rays}")


class WalkSettings(NamedTuple):
    """The options the compiled kernels read (one argument)."""

    both_sides: bool  # detectors count light from both sides
    nee: bool  # next-event estimation on
    nee_samples: int  # shadow rays per scatter vertex and detector
    roulette_w: float  # Russian roulette threshold, W (rr_threshold x start weight)
    eps_mm: float  # self-intersection offset
    record_paths: bool
    nee_part: np.ndarray  # (P,) bool: the part's interaction kind does NEE (Capability.NEE), so a walk
    # hit on a detector right after a scatter there keeps only its MIS share


def walk_settings(options: TraceOptions, eps_mm: float, start_weight_w: float, nee_part) -> WalkSettings:
    est, out = options.estimator, options.output
    return WalkSettings(both_sides=out.detector_sides == "both", nee=bool(est.nee),
                        nee_samples=int(est.nee_samples), roulette_w=float(est.rr_threshold) * start_weight_w,
                        eps_mm=float(eps_mm), record_paths=bool(out.record_paths),
                        nee_part=np.ascontiguousarray(nee_part, dtype=np.bool_))
