"""Progress that also reaches a log file: when stderr is not a terminal, a plain line every few
seconds (a heartbeat too), nothing for short runs; on a terminal, tqdm's bar."""
import io
import time

from straylight.progress import progress_bar


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_a_log_gets_whole_lines_every_interval_even_without_steps(monkeypatch):
    monkeypatch.setenv("STRAYLIGHT_PROGRESS_INTERVAL_S", "0.2")
    log = io.StringIO()
    with progress_bar(total=4, desc="PST sweep", unit="angle", file=log) as bar:
        bar.update(1)
        time.sleep(1.1)  # a long step: no update, the heartbeat still writes
        bar.set_postfix_str("20 deg: round 3")
        bar.update(3)
        time.sleep(0.3)
    text = log.getvalue()
    lines = text.splitlines()
    assert "\r" not in text and text.endswith("\n")
    assert len(lines) >= 4, text  # ~1.4 s at one line per 0.2 s
    assert all(line.startswith("PST sweep:") for line in lines)
    assert "1/4" in lines[0] and any("4/4" in line and "20 deg: round 3" in line for line in lines), text


def test_a_short_run_writes_nothing_to_a_log(monkeypatch):
    monkeypatch.setenv("STRAYLIGHT_PROGRESS_INTERVAL_S", "5")
    log = io.StringIO()
    for _ in progress_bar(range(100), desc="quick", file=log):
        pass
    assert log.getvalue() == ""
    silent = io.StringIO()
    with progress_bar(total=3, enabled=False, file=silent) as bar:
        bar.update(3)
    assert silent.getvalue() == ""


def test_a_terminal_gets_the_tqdm_bar():
    tty = _Terminal()
    with progress_bar(total=3, desc="trace", unit="chunk", file=tty) as bar:
        bar.update(3)
    assert "\r" in tty.getvalue() and "trace" in tty.getvalue()
