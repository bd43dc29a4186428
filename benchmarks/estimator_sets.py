"""The history estimator sets the benchmarks time the default against, registered with
:func:`straylight.analyses.estimators.register_estimator_set` (they are not part of the public API).

``chains``
    the default without ``entrance_sampling`` (uniform entrance points): the set before it, to measure
    what it buys on scenes with lenses.
``split``
    the default with ``reflection_split`` (single reflections into a detector by expected value)
    instead of ``delta_chain``: the set before the interface chains, to measure what they buy.
``roulette``
    the default without ``delta_chain`` or ``reflection_split`` (to measure what they buy).
``lobes``
    ``roulette`` with the engine's roulette threshold (1e-3): the set before the roulette change,
    kept to measure what it buys.
``first_lobe``
    ``lobes`` without the second-vertex lobe draw (to measure what each draw buys).
``manifold``
    the default with specular next-event estimation through every sequence of up to two interfaces
    (``specular_nee=2``, ``specular_nee_sequences="all"``; the default joins scatter vertices to the
    detector through a lens face's reflection or a lens's thick mirror), to measure what the two
    refractions buy.
``reflections``
    the default with specular next-event estimation through one interface only (``specular_nee=1``: the
    single reflections), the set before the thick mirrors, to measure what they buy.
``reverse``
    the default without specular next-event estimation (``specular_nee=0``): the set before it, to measure
    what it buys.
``no_ends``
    the default without ``tree_ends`` (the trees' branch ends take no lobe draw): the set before them, to
    measure what they cost and buy.
``walk_direct``
    the default without ``direct_area`` (the walk alone finds the light that reaches the detector straight):
    the set before it, to measure what it buys at a baffle's cut-off.
``baseline``
    the first estimator set (first-vertex sampling joined to the detector by a uniform point only,
    roulette at 1e-3), so a benchmark can time before and after in one run.

As a command: ``python benchmarks/estimator_sets.py pst ... --estimators baseline`` is
``straylight pst`` with these sets registered (what benchmarks/newtonian_pst.py runs).
"""
from __future__ import annotations

import sys
from dataclasses import replace

if __name__ == "__main__":  # the command as ``straylight`` runs it: one BLAS thread, set before numpy loads
    from straylight.cli.main import single_threaded_blas

    single_threaded_blas()

from straylight.analyses.estimators import ANALYSIS_RR_THRESHOLD, ESTIMATOR_SETS, register_estimator_set  # noqa: E402
from straylight.engine.options import EstimatorOptions  # noqa: E402

_LOBES = EstimatorOptions(first_vertex_sampling=True, second_vertex_sampling=True, vertex_lobe_sampling=True,
                          second_vertex_lobe_sampling=True)
HISTORY_SETS = {
    "chains": replace(_LOBES, rr_threshold=ANALYSIS_RR_THRESHOLD, delta_chain=4),
    "split": replace(_LOBES, rr_threshold=ANALYSIS_RR_THRESHOLD, reflection_split=True),
    "lobes": _LOBES,
    "roulette": replace(_LOBES, rr_threshold=ANALYSIS_RR_THRESHOLD),
    "first_lobe": replace(_LOBES, second_vertex_lobe_sampling=False),
    "baseline": EstimatorOptions(first_vertex_sampling=True, second_vertex_sampling=True),
    "entrance": replace(_LOBES, rr_threshold=ANALYSIS_RR_THRESHOLD, delta_chain=4, entrance_sampling=True),
}


def register() -> None:
    """Make every history set a choice of ``estimator_options`` and of ``--estimators``."""
    for name, options in HISTORY_SETS.items():
        register_estimator_set(name, options)
    register_estimator_set("manifold", replace(ESTIMATOR_SETS["default"], specular_nee=2, specular_nee_sequences="all"))
    register_estimator_set("reflections", replace(ESTIMATOR_SETS["default"], specular_nee=1, specular_nee_sequences="all"))
    register_estimator_set("reverse", replace(ESTIMATOR_SETS["default"], specular_nee=0))
    register_estimator_set("walk_direct", replace(ESTIMATOR_SETS["default"], direct_area=False))
    register_estimator_set("no_ends", replace(ESTIMATOR_SETS["default"], tree_ends=False))


register()

if __name__ == "__main__":
    from straylight.cli.main import main

    sys.exit(main(sys.argv[1:]))
