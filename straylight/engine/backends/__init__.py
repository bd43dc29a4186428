"""Where batches run (docs/engine.md, "Backends"): this process one batch after another or on a
shared thread pool (:mod:`.threads`), a dask cluster (:mod:`.dask`), whose local worker processes
are forked from a server (:mod:`.fork_server`) that has loaded the kernels (:mod:`.preload`)."""
