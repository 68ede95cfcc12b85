"""Progress bars for long command-line work: tqdm when the ``cli`` extra is installed."""
from __future__ import annotations

import sys
import threading
import time
from contextlib import contextmanager

LOG_INTERVAL_S = 20.0  # not a terminal (a log file, CI): one line at most this often


def progress(iterable=None, total=None, desc=None, unit="it", disable=False, interval_s: float = LOG_INTERVAL_S):
    """Wrap an iterable in a tqdm bar on stderr; a no-op wrapper when tqdm is not installed.

    On a terminal the bar redraws in place; written to a log (stderr not a terminal) it prints a
    whole line every `LOG_INTERVAL_S` seconds and one at the end, not a carriage-return update
    per step (17 kB of them per run before); ``interval_s`` sets that spacing."""
    try:
        from tqdm.auto import tqdm
    except ImportError:  # the runtime API must work with the three core dependencies only
        return iterable if iterable is not None else _NullBar()
    stream = sys.stderr
    if getattr(stream, "isatty", lambda: False)():
        return tqdm(iterable, total=total, desc=desc, unit=unit, disable=disable, dynamic_ncols=True)
    return tqdm(iterable, total=total, desc=desc, unit=unit, disable=disable, file=_Lines(stream),
                mininterval=interval_s, maxinterval=3 * interval_s, ncols=100)


@contextmanager
def heartbeat(echo, what: str, every_s: float = 10.0):
    """While the ``with`` body runs, ``echo`` a line ``  … what: N s`` every ``every_s`` seconds
    (a phase with no bar of its own, e.g. a child process, still says it is alive)."""
    stop = threading.Event()
    start = time.perf_counter()

    def beat():
        while not stop.wait(every_s):
            echo(f"  … {what}: {time.perf_counter() - start:.0f} s")

    thread = threading.Thread(target=beat, name="heartbeat", daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()


class _Lines:
    """A file for tqdm that turns its in-place redraws into whole lines (for logs)."""

    def __init__(self, stream):
        self._stream = stream

    def write(self, text: str) -> None:
        text = text.replace("\r", "").rstrip("\n")
        if text.strip():
            self._stream.write(text + "\n")

    def flush(self) -> None:
        self._stream.flush()


class _NullBar:
    def update(self, n=1):
        pass

    def set_postfix(self, *a, **k):
        pass

    def close(self):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False
