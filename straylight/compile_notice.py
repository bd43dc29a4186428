"""The first run's announcement: the tracer's kernels are compiled once (numba), which takes tens of seconds
before the first ray; said up front so that a progress bar at 0 does not look like a hang.

The kernels are cached by content and package path (:mod:`materials.jit_cache`), in
``NUMBA_CACHE_DIR/straylight_engine`` for the engine's: no index file there means nothing is compiled yet.
"""
from __future__ import annotations

from pathlib import Path

TRACING_COMMANDS = frozenset({"pst", "paths", "critical", "study", "trace", "thermal", "exchange", "design", "view"})


def first_compile_notice(cache_folder=None) -> str | None:
    """A one-line notice if the engine's kernels are not compiled yet in ``cache_folder`` (default: the
    numba cache folder this process uses), else None."""
    if cache_folder is None:
        from atomicio.cache_dirs import configure_numba_cache

        cache_folder = configure_numba_cache()
    engine = Path(cache_folder) / "straylight_engine"
    if engine.is_dir() and any(engine.glob("*.nbi")):
        return None
    return (f"first run: compiling the tracer's kernels (once, about half a minute before the first ray; "
            f"kept in {cache_folder} for every later run and every clone of the project)")
