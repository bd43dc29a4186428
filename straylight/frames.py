"""Rows of dicts as a pandas DataFrame, and the axes helpers of the result plots.

``data_frame(rows, columns)`` is what every result's ``to_pandas()`` calls (pandas is optional:
``pip install pandas``); ``own_axes`` / ``finish_axes`` let a plot draw into given axes or its own
figure, written atomically (atomicio) when a path is given.
"""
from __future__ import annotations

import atomicio


def data_frame(rows: list[dict], columns):
    """A pandas DataFrame of ``rows`` (dicts) with ``columns`` in this order (missing keys: NaN/None)."""
    try:
        import pandas as pd
    except ImportError as exc:  # an optional dependency: say how to get it
        raise ImportError("to_pandas() needs pandas: pip install pandas") from exc
    return pd.DataFrame([{c: r.get(c) for c in columns} for r in rows], columns=list(columns))


def own_axes(ax, size):
    """(ax, own): the given axes, or new ones of a figure of ``size`` inches the caller owns."""
    import matplotlib.pyplot as plt

    if ax is not None:
        return ax, False
    return plt.subplots(figsize=size, dpi=120)[1], True


def finish_axes(ax, own, path):
    """Lay out an owned figure and write it to ``path`` (atomically) when given; returns ``ax``."""
    import matplotlib.pyplot as plt

    if own:
        ax.figure.tight_layout()
        if path is not None:
            atomicio.write_figure(ax.figure, path)
            plt.close(ax.figure)
    return ax
