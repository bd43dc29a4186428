"""Baffle synthesis: design the vanes of a tube (CONTRACTS 4.6, docs/design.md).

- :mod:`straylight.design.construction`: Freniere's geometric construction and the exact
  lit / seen wall analysis (no tracing), for any tube: :func:`construct_vanes`.
"""
from straylight.design.construction import (BaffleSpec, DesignError, Layout, Vane, analyse_layout, construct,
                                            construct_vanes, evenly_spaced, layout_at)

__all__ = ["BaffleSpec", "DesignError", "Layout", "Vane", "analyse_layout", "construct", "construct_vanes",
           "evenly_spaced", "layout_at"]
