"""The one progress bar of the project: tqdm on stderr, shown only when asked, removed when done.

On a terminal it is tqdm's bar. When stderr is not a terminal (a run logged to a file, a batch job),
a bar redrawn in place would leave one endless line, so it prints a plain line instead -- ``desc:
n/total [elapsed<left, rate, postfix]`` -- every :data:`LOG_INTERVAL_S` seconds while it runs (also
when no step finishes in between: a heartbeat), and nothing for runs shorter than that (tests and
quick commands stay quiet). ``STRAYLIGHT_PROGRESS_INTERVAL_S`` sets the interval."""
from __future__ import annotations

import os
import sys
import threading

LOG_INTERVAL_S = 5.0


def log_interval_s() -> float:
    """Seconds between progress lines in a log (``STRAYLIGHT_PROGRESS_INTERVAL_S``, default 5)."""
    try:
        value = float(os.environ.get("STRAYLIGHT_PROGRESS_INTERVAL_S", LOG_INTERVAL_S))
    except ValueError:
        return LOG_INTERVAL_S
    return value if value > 0 else LOG_INTERVAL_S


def progress_bar(iterable=None, total=None, desc=None, unit="it", enabled=True, initial=0, file=None):
    """A tqdm bar over ``iterable`` (or a manual one of ``total`` steps, ``bar.update(k)``) on stderr
    (or ``file``): a bar on a terminal, a line every few seconds elsewhere, nothing if not ``enabled``."""
    from tqdm import tqdm

    stream = sys.stderr if file is None else file
    terminal = bool(getattr(stream, "isatty", lambda: False)())
    kwargs = {"total": total, "desc": desc, "unit": unit, "initial": initial, "file": stream, "leave": False}
    if not enabled or terminal:
        return tqdm(iterable, disable=not enabled, **kwargs)
    return _log_lines_class()(iterable, interval_s=log_interval_s(), **kwargs)


_LOG_LINES = None


def _log_lines_class():
    """tqdm subclass that writes whole lines at most every ``interval_s`` seconds (made once, on first use:
    tqdm is imported lazily)."""
    global _LOG_LINES
    if _LOG_LINES is not None:
        return _LOG_LINES
    from tqdm import tqdm

    class LogLines(tqdm):
        def __init__(self, iterable=None, interval_s=LOG_INTERVAL_S, **kwargs):
            self._interval_s = float(interval_s)
            self._next_line = None  # set once tqdm has its clock
            self._stop = threading.Event()
            super().__init__(iterable, mininterval=self._interval_s, ncols=0, dynamic_ncols=False, **kwargs)
            self._next_line = self.start_t + self._interval_s
            self._beat = threading.Thread(target=self._heartbeat, name="progress-lines", daemon=True)
            self._beat.start()

        def _heartbeat(self):
            while not self._stop.wait(self._interval_s):
                self.refresh()

        def display(self, msg=None, pos=None):
            if msg == "":  # tqdm clearing the bar at close: nothing to clear in a log (and no '\r')
                return False
            if self._next_line is None:  # tqdm's first draw
                return True
            now = self._time()
            if now < self._next_line:
                return True
            self._next_line = now + self._interval_s
            line = (self.__str__() if msg is None else msg).strip()
            if line:
                self.fp.write(line + "\n")
                self.fp.flush()
            return True

        def close(self):
            self._stop.set()
            super().close()

    _LOG_LINES = LogLines
    return LogLines
