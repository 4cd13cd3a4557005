"""When progress is reported: by time as well as by step, so that no phase goes quiet.

The trainer reports every ``Pace.every`` steps and after any step that ends ``Pace.seconds`` or
more after its last report, so a phase of slow steps still reports about once a second. The
command line's plain-line reporters print a line at least every `LINE_SECONDS`: a `Ticker` thread
asks them once a `TICK_SECONDS`, so one long call (an encode, a GLSL check) cannot silence them,
and they print at most one such line per tick. Every clock here is an argument, so tests drive
them with a fake one.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Callable

__all__ = ["Clock", "LINE_SECONDS", "TICK_SECONDS", "Pace", "Pacer", "Ticker"]

Clock = Callable[[], float]

LINE_SECONDS = 8.0  # a plain-line reporter's longest silence; one tick later it has printed: under 10 s
TICK_SECONDS = 1.0  # how often a Ticker asks; no more than one heartbeat line per tick


@dataclass(frozen=True)
class Pace:
    """When the trainer reports: every ``every`` steps, and after any step that ends ``seconds``
    or more (by ``clock``) after the last report. Reports change nothing the training computes."""

    every: int = 50
    seconds: float = 1.0
    clock: Clock = time.monotonic


class Pacer:
    """Whether ``seconds`` of ``clock`` have passed since the last `mark` (or since it was made)."""

    def __init__(self, seconds: float, clock: Clock = time.monotonic):
        self.seconds, self.clock = seconds, clock
        self.last = clock()

    def due(self) -> bool:
        return self.clock() - self.last >= self.seconds

    def mark(self) -> None:
        self.last = self.clock()


class Ticker:
    """Calls ``fn`` every ``seconds`` on a daemon thread while entered: what lets a reporter print
    while the thread it reports on is inside one long call. Output that closed (OSError) ends it."""

    def __init__(self, fn: Callable[[], None], seconds: float = TICK_SECONDS):
        self.fn, self.seconds = fn, seconds
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def __enter__(self) -> "Ticker":
        self._thread = threading.Thread(target=self._run, name="bcfpipe-progress", daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None

    def _run(self) -> None:
        while not self._stop.wait(self.seconds):
            try:
                self.fn()
            except OSError:
                return
