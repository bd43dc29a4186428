"""The last sampling table of each kind (first- and second-vertex), kept per process so that the
rounds of ``--target-rel-error`` (straylight.analyses.precision: one trace per round, same seed)
build it once. A table depends only on the geometry, the materials, the sources, the seed and the
detector options, so reusing it changes no number; the key holds exactly those (materials and
sources by identity, kept alive by the entry so their ids stay theirs)."""
from __future__ import annotations

import threading

_LAST: dict = {}
_LOCK = threading.Lock()


def _key(spec):
    opt = spec.options
    return (spec.token, spec.seed, tuple(id(s) for s in spec.sources), tuple(id(m) for m in spec.materials),
            opt.detector_sides, opt.polarization)


def last_table(kind: str, spec, build, cache: bool = True):
    """The table of ``kind`` for ``spec``: the one kept from the previous call with the same key,
    else ``build()`` (kept, one per kind)."""
    if not cache:
        return build()
    key = _key(spec)
    with _LOCK:
        hit = _LAST.get(kind)
        if hit is not None and hit[0] == key:
            return hit[2]
    table = build()
    with _LOCK:
        _LAST[kind] = (key, (spec.sources, spec.materials), table)
    return table
