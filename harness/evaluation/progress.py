"""Progress of an evaluation's runs: a live bar on a terminal, and a plain line at most every ``LOG_INTERVAL_S``
in a log.

tqdm redraws its bar with carriage returns; in a file (``make evaluate > log 2>&1``, a cluster's job log) every
redraw stays, one per finished run (about 40 kB for the default scenario's 480 runs). When the stream is not a
terminal a line is written when a run finishes at least ``LOG_INTERVAL_S`` after the previous line, and one at
the end: an evaluation of ``m`` minutes writes at most ``2 m + 1`` lines of about 60 bytes.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import IO

LOG_INTERVAL_S = 30.0       # the bound for a log: a line at most every 30 s


class LogProgress:
    """Plain progress lines for a log: ``name: 120/480 runs, 3 min 5 s, about 9 min left``."""

    def __init__(self, total: int, desc: str, stream: IO[str], clock: Callable[[], float] = time.monotonic,
                 interval_s: float = LOG_INTERVAL_S):
        self.total, self.desc, self.stream, self.clock, self.interval_s = total, desc, stream, clock, interval_s
        self.n = 0
        self.start = self.last = clock()

    def update(self, n: int = 1) -> None:
        self.n += n
        now = self.clock()
        if now - self.last >= self.interval_s and self.n < self.total:
            self.last = now
            self._line(now)

    def close(self) -> None:
        if self.n:
            self._line(self.clock())

    def _line(self, now: float) -> None:
        elapsed = now - self.start
        left = f", about {_duration(elapsed * (self.total - self.n) / self.n)} left" if 0 < self.n < self.total else ""
        self.stream.write(f"{self.desc}: {self.n}/{self.total} runs, {_duration(elapsed)}{left}\n")
        self.stream.flush()


def _duration(seconds: float) -> str:
    seconds = int(round(seconds))
    if seconds < 60:
        return f"{seconds} s"
    minutes, seconds = divmod(seconds, 60)
    if minutes < 60:
        return f"{minutes} min {seconds} s"
    hours, minutes = divmod(minutes, 60)
    return f"{hours} h {minutes} min"


class _Silent:
    def update(self, n: int = 1) -> None:
        pass

    def close(self) -> None:
        pass


def progress(total: int, desc: str, enabled: bool = True, stream: IO[str] | None = None):
    """An object with ``update(n)`` and ``close()`` that shows ``total`` runs' progress on ``stream`` (standard
    error): tqdm's live bar on a terminal, ``LogProgress`` lines otherwise, nothing when not ``enabled``."""
    stream = sys.stderr if stream is None else stream
    if not enabled:
        return _Silent()
    isatty = getattr(stream, "isatty", None)
    if isatty is not None and isatty():
        from tqdm import tqdm

        return tqdm(total=total, desc=desc, unit="run", leave=False, file=stream)
    return LogProgress(total, desc, stream)
