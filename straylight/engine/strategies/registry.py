"""The engine's strategies, in order (docs/engine.md, "Strategies"): the plan decides on them, ``trace()``
builds their tables and the walk runs their hooks in this order (the order of the walk's tally writes:
keep it, or goldens move). straylight.engine.estimators.ESTIMATORS is their declarations.

A new strategy: one module in this package (a :class:`~straylight.engine.strategies.base.Strategy`
subclass and its instance), one line here, one row in tests/straylight/test_engine_contract.py.
"""
from __future__ import annotations

from straylight.engine.strategies.base import Strategy
from straylight.engine.strategies.delta_chain import DELTA_CHAIN
from straylight.engine.strategies.direct_area import DIRECT_AREA
from straylight.engine.strategies.entrance import ENTRANCE
from straylight.engine.strategies.first_vertex import FIRST_VERTEX, FIRST_VERTEX_LOBE
from straylight.engine.strategies.lens_vertex import LENS_VERTEX
from straylight.engine.strategies.nee import NEE
from straylight.engine.strategies.reflection_split import REFLECTION_SPLIT
from straylight.engine.strategies.reverse_chain import REVERSE_CHAIN
from straylight.engine.strategies.second_vertex import SECOND_VERTEX, SECOND_VERTEX_LOBE
from straylight.engine.strategies.specular_nee import SPECULAR_NEE
from straylight.engine.strategies.target_mis import TARGET_MIS

STRATEGIES: tuple[Strategy, ...] = (
    NEE,
    FIRST_VERTEX,
    FIRST_VERTEX_LOBE,
    SECOND_VERTEX,
    SECOND_VERTEX_LOBE,
    REFLECTION_SPLIT,
    DELTA_CHAIN,
    ENTRANCE,
    TARGET_MIS,
    REVERSE_CHAIN,
    SPECULAR_NEE,
    DIRECT_AREA,
    LENS_VERTEX,
)

BY_NAME: dict[str, Strategy] = {s.name: s for s in STRATEGIES}
