"""Analyses built on the tracer: PST sweeps, stray-light path reports, critical and
illuminated objects, design sweeps, and the study report.

The shared types (a :class:`~straylight.analyses.types.Setup`, its beam and entrance, the PST and
sweep results) live in :mod:`straylight.analyses.types`; every grid of points (``pst``, the study's
sweeps, ``--model`` sweeps, ``design vanes``) runs on :func:`straylight.analyses.grid.run_grid`;
where it runs is one :class:`straylight.execution.Execution`."""
