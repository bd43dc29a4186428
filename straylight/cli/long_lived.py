"""Start-up without garbage collections: the objects a command makes while it starts (the modules
it imports, its parser, numba's registries, the loaded scene) live as long as the process.

CPython's collector scans each new container object in the young generation, and again in the
middle one, before it reaches the old generation (which ``straylight`` seldom collects:
``straylight.cli.main._rarer_full_collections``); the objects of the start-up are ~10^5 and are never
garbage, so those scans were 0.06 CPU s of a ``straylight pst`` command (gc.callbacks, 20 deg on the
guide scope) that found nothing worth freeing (numba's own start left some 750 small IR objects, no array).
:func:`long_lived_objects` turns automatic collections off for a block of the start-up and then
moves everything it made into the collector's permanent generation (``gc.freeze``, as CPython's
documentation suggests for objects that live as long as the process), so they are never scanned.
"""
from __future__ import annotations

import gc
from contextlib import contextmanager


_FROZEN: set = set()


@contextmanager
def long_lived_objects(stage: str):
    """No automatic garbage collection in the block; after it, every object alive (the block's and
    older) goes to the permanent generation (``gc.freeze``) and collections resume as they were.
    Once per ``stage`` and process (``"parser"``, ``"scene"``): a reference cycle made in the block is
    never freed, so a process that runs many commands (the tests call :func:`straylight.cli.main.main`
    over and over) freezes each stage's objects once, and after that collects as usual."""
    if stage in _FROZEN:
        yield
        return
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        _FROZEN.add(stage)
        gc.freeze()
        if enabled:
            gc.enable()
