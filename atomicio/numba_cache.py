"""Importing this module points numba's on-disk cache at the user's cache folder, before any kernel
is compiled (:func:`atomicio.cache_dirs.configure_numba_cache`). ``materials``, ``geometry`` and
``straylight`` import it first thing, so whichever package compiles first finds it set."""
from atomicio.cache_dirs import configure_numba_cache

NUMBA_CACHE_DIR = configure_numba_cache()
