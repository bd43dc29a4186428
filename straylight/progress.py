"""The one progress bar of the project: tqdm on stderr, shown only when asked and stderr is a
terminal (so logs and tests stay clean), removed when done."""
from __future__ import annotations

import sys


def progress_bar(iterable=None, total=None, desc=None, unit="it", enabled=True, initial=0):
    """A tqdm bar over ``iterable`` (or a manual one of ``total`` steps, ``bar.update(k)``)."""
    from tqdm import tqdm

    return tqdm(iterable, total=total, desc=desc, unit=unit, initial=initial, file=sys.stderr, leave=False,
                disable=not (enabled and sys.stderr.isatty()))
