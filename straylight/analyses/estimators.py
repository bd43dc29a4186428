"""The estimator sets the analyses trace with (pst, paths, study, design sweeps).

``default``
    next-event estimation, first-vertex sampling with the lobe's own draw
    (``vertex_lobe_sampling``), second-vertex sampling with the lobe's own draw at its
    critical point (``second_vertex_lobe_sampling``), and Russian roulette only below
    ``ANALYSIS_RR_THRESHOLD`` = 1e-5 of a ray's start weight. Roulette's survivors carry the
    threshold weight: at 1e-3 (the engine's default) a glossy double or triple scatter that was
    rouletted at its last vertex and then went along its lobe into the detector carried 1e-3 of a
    start weight, ~1500x the mean contribution at 30 deg on the Newtonian benchmark: those rays held
    78-84 % of the variance there and 99 % at 50 deg on the built-in z302 tube (docs/engine.md,
    "Russian roulette and the glossy tails").
    It also follows runs of up to 32 Fresnel and specular interfaces (``optical_surface`` parts) with at
    most 2 reflections among them into a detector by splitting, both branches with their expected
    weights (``delta_chain``, ``delta_chain_reflections``,
    straylight.engine.delta_chain): on a refractor the lens's own two-reflection ghost "vane -> lens
    (T) -> back face (R) -> front face (R) -> back face (T) -> sensor" was found by ~R^2 = 1.6e-3 of
    the rays that entered the lens, with ~600x the weight, and the single reflections "vane -> lens
    face (R) -> sensor" by ~4 %, with 25x.

    With a refracting material in the scene (``ComponentFlags.DELTA_TRANSMISSION``: a lens, a
    window) it also draws the source's entrance points from a density learnt by a pilot of 1e4-3e4 rays
    (``entrance_sampling``, straylight.engine.entrance_sampling): behind a lens only a few entrance
    points reach a small sensor (the ghost of the direct beam), and a uniform beam finds them by chance.
    A tenth of that density is drawn from the entrance points that light, through the lens, the scatter
    points the detector sees (the lens cell's glints: straylight.engine.strategies.entrance, LENS_COMPONENT),
    which a pilot of 3e4 rays leaves with little mass.

    With a refracting material it also traces, per ray, an eye chain from the detector back through
    up to 32 interfaces, at most 2 of them reflections (``reverse_chain``, straylight.engine.reverse_chain):
    the scatter the lens's
    image or ghosts carry onto the sensor ("dew shield -> lens x4 -> sensor" at 30-60 deg on a
    refractor, which the walk found by chance) is joined to the source and to the walk's scatter
    vertices, sharing those runs with the split trees by the balance heuristic.

    With a refracting material it also joins the walk's plain scatter vertices to the detector through
    a lens face's reflection or a lens's thick mirror (``specular_nee = 3``, ``specular_nee_sequences =
    "mirrors"``, straylight.engine.specular_nee, Newton's method on the surfaces): "vane -> lens back
    face (R) -> sensor", a vane behind the lens seen in its flat back face, held 86 % of the variance at
    5 deg on the guide scope and made 20 deg's error bar unreliable (VOV up to 0.9); "vane -> lens_back (T)
    -> lens_front (R, inside) -> lens_back (T) -> sensor", tried from a vertex with probability 0.25
    min(1, w / w0), held the 5 and 10 deg tails (VOV up to 0.44 and 0.79 at 1e5 rays; with it 0.04 and 0.019). The
    reflections cost 10-20 % CPU per ray, the thick mirrors 2-20 % more (docs/engine.md, "Specular
    next-event estimation", "Thick mirrors").

    With a refracting material the split trees' branches that end on a glossy part after a reflection (the beam's
    own light reflected inside a lens onto its cell or a vane) also take a lobe draw there, followed by a split
    tree of its own (``tree_ends``, straylight.engine.tree_ends): the walk reached such a point by its ~4 %
    reflection choice, and on the guide scope at 15 deg the cell's lip, lit so and seen through the lens at a
    glint, was found so rarely that runs of 1e5 rays read 5-10 % low with error bars that did not cover it
    (12 seeds: RMS z 3.3, 4 beyond 3 sigma; with the draws RMS z 0.94 for +4 % CPU; docs/engine.md, "Lobe draws
    at the trees' branch ends").

    At the glints of a glossy lobe on a detector (a vertex whose NEE toward a fixed detector point is
    predicted above 3e-7 of a start weight) it takes up to 64 NEE samples and as many lobe draws,
    weighed as one multi-sample MIS (``nee_split``, straylight.engine.nee_split): on the guide scope at
    15 deg the lens cell's bore, grazed by the beam behind the lens, is nearly a mirror there, and one
    NEE point and one lobe draw saw its peak on the sensor by chance (docs/engine.md, "NEE splitting at
    glints").

    For one collimated beam on a flat detector (analytic surfaces: planes and cylinders only) it also computes
    the light that reaches the detector straight, exactly, by 2-D clipping along the beam (``direct_area``,
    straylight.engine.direct_area): near a baffle's cut-off that light passes a sliver the walk meets once in
    ~1e5 rays (the built-in tube at 14 deg: 17 % of the power), which made the point's error bar wrong or
    unreliable.

Other sets (the history sets the benchmarks time the default against) are registered by
:func:`register_estimator_set`: ``benchmarks/estimator_sets.py`` registers them for the benchmark
runs and for its ``straylight`` command wrapper.
"""
from __future__ import annotations

from dataclasses import replace

from materials.flags import ComponentFlags, flags_of
from straylight.engine.options import EstimatorOptions, TraceOptions

#: Russian roulette threshold of the default set, relative to a ray's start weight
ANALYSIS_RR_THRESHOLD = 1e-5
#: interfaces a split tree of the default set follows: a cap. A two-reflection ghost of a lens of N
#: surfaces meets up to 3 N - 2 (a singlet 4, a cemented doublet 7: front (T), cement (T), back (R),
#: cement (T), front (R), cement (T), back (T); a Cooke triplet 16, a double Gauss of 10 surfaces 28):
#: 32 reaches every two-reflection ghost of a lens of up to 11 surfaces
DELTA_CHAIN_INTERFACES = 32
#: reflections a split tree of the default set follows among them (a ghost's order): this, not the
#: cap, bounds the trees (the transmissions between the reflections need no budget of their own)
DELTA_CHAIN_REFLECTIONS = 2

#: most NEE samples and lobe draws at a glint of the default set (straylight.engine.nee_split)
NEE_SPLIT = 64

#: lobe draws of a glossy vertex lit by the source followed into the split trees (straylight.engine.tree_split;
#: on the guide scope 4 beat 2 and 8, docs/engine.md "Lobe draws into the split trees")
TREE_SPLIT = 4

#: the sets: presets of the estimator options (NEE on, the engine's other defaults unless named)
ESTIMATOR_SETS = {
    "default": EstimatorOptions(first_vertex_sampling=True, second_vertex_sampling=True, vertex_lobe_sampling=True,
                                second_vertex_lobe_sampling=True, rr_threshold=ANALYSIS_RR_THRESHOLD,
                                delta_chain=DELTA_CHAIN_INTERFACES, delta_chain_reflections=DELTA_CHAIN_REFLECTIONS,
                                entrance_sampling=True,
                                reverse_chain=DELTA_CHAIN_INTERFACES, specular_nee=3,
                                specular_nee_sequences="mirrors", nee_split=NEE_SPLIT,
                                tree_split=TREE_SPLIT, tree_ends=True, direct_area=True),
}
#: the default set with the scatter points lit through a lens area-sampled and joined to the beam through it
#: (straylight.engine.lens_vertex): for a lens whose cell or mount the beam lights behind the glass, seen by the
#: detector at a glint (the guide scope at 15 deg, before the entrance table's lens component: the bore's family,
#: 3.5 % -> 0.8 % at 1e5 rays for seed 1); it costs 0.7-0.9 CPU s per 6e4 rays where the beam lights the tube behind
#: the lens at all, which is why it is not in the default set
ESTIMATOR_SETS["lens"] = replace(ESTIMATOR_SETS["default"], lens_vertex=True)
#: the default set with specular NEE also through a singlet's two-reflection ghosts, joined to the eye chains and the
#: lobe draws by the three-way balance (straylight.engine.specular_nee, "Ghosts"): for points the beam lights in front
#: of a lens whose ghost carries their light onto the sensor (the guide scope at 45 deg: 0.48-0.60 % at 1e5 rays
#: against 0.85-1.49 %, CPU s x rel^2 2-4x lower); ~1 CPU s more per 6e4 rays where the eye chains run, which is why
#: it is not in the default set (docs/engine.md, "Ghost connections")
ESTIMATOR_SETS["ghosts"] = replace(ESTIMATOR_SETS["default"], specular_nee=4)


def register_estimator_set(name: str, options: EstimatorOptions) -> None:
    """Add (or replace) the estimator set ``name``: :func:`estimator_options` and the ``--estimators``
    choices of a command built afterwards accept it. ``default`` cannot be replaced."""
    if name == "default":
        raise ValueError("the default estimator set cannot be replaced")
    if not isinstance(options, EstimatorOptions):
        raise TypeError(f"estimator set {name!r}: expected EstimatorOptions, got {type(options).__name__}")
    ESTIMATOR_SETS[name] = options


def estimator_options(name: str = "default", options: TraceOptions | None = None, materials=None) -> TraceOptions:
    """``options`` (default ``TraceOptions()``) with the estimator options of the set ``name``.
    ``materials`` (the scene's models, a dict or a list; optional): when none declares a peaked lobe
    (``ComponentFlags.GLOSSY``), the roulette threshold stays the one of ``options`` (the engine's),
    as the lobe draws stay off there: the survivor tail comes from narrow lobes, and on the Lambertian
    benchmark tube the lower threshold cost ~25 % CPU for nothing."""
    if name not in ESTIMATOR_SETS:
        raise ValueError(f"unknown estimator set {name!r}; known: {', '.join(ESTIMATOR_SETS)}")
    options = options or TraceOptions()
    chosen = ESTIMATOR_SETS[name]
    if materials is not None:
        models = list(materials.values()) if isinstance(materials, dict) else list(materials)
        if not any(flags_of(m) & ComponentFlags.GLOSSY for m in models if not isinstance(m, str)):
            chosen = replace(chosen, rr_threshold=options.estimator.rr_threshold, nee_split=options.estimator.nee_split)
        if not any(flags_of(m) & ComponentFlags.DELTA_TRANSMISSION for m in models if not isinstance(m, str)):
            chosen = replace(chosen, entrance_sampling=False, reverse_chain=0, specular_nee=0, tree_ends=False)
    return replace(options, estimator=chosen)
