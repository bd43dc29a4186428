"""Independent fits of one diagnosis, run serially or on a ``concurrent.futures`` executor the
caller owns (DESIGN: no home-made pools).

Use a ``ProcessPoolExecutor``: the fits are Python-heavy and hold the GIL, so threads gain
little (~1.2x on 2 cores) and would share one problem's caches. Each task carries the
:class:`rig.diagnose.problem.Problem` (pickled without its caches); a worker keeps the first
copy it receives of each problem (by ``problem.token``), so its node caches stay warm for the
rest of the diagnosis. Results come back in submission order: the same as the serial loop.
"""
from __future__ import annotations

_PROBLEMS: dict = {}  # in a worker process: problem token -> the Problem (caches warm)
_KEEP = 4


def _call(problem, fn, args):
    local = _PROBLEMS.get(problem.token)
    if local is None:
        while len(_PROBLEMS) >= _KEEP:
            _PROBLEMS.pop(next(iter(_PROBLEMS)))
        _PROBLEMS[problem.token] = local = problem
    return fn(local, *args)


def _bar(iterable, total, desc, show):
    if not show:
        return iterable
    from straylight.progress import progress_bar

    return progress_bar(iterable, total=total, desc=desc)


def run_tasks(problem, fn, arglist, executor=None, progress: bool = False, desc: str = "") -> list:
    """``[fn(problem, *args) for args in arglist]``, on ``executor`` when one is given (``fn`` must
    be a module-level function, so it pickles)."""
    arglist = [tuple(a) for a in arglist]
    if executor is None or len(arglist) <= 1:
        return [fn(problem, *a) for a in _bar(arglist, len(arglist), desc, progress)]
    futures = [executor.submit(_call, problem, fn, a) for a in arglist]
    return [f.result() for f in _bar(futures, len(futures), desc, progress)]
