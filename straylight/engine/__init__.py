"""The Monte Carlo engine, one file per stage (docs/engine.md). The entry point is
:func:`straylight.trace.trace`."""
