"""Training seconds: wall time that can be paused, so evaluation inside training is not counted.

>>> clock = Clock(elapsed=10.0)
>>> with clock.paused():
...     pass
>>> clock.seconds() >= 10.0
True
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager


class Clock:
    """Seconds since the clock started (plus ``elapsed``, e.g. from a checkpoint), pauses excluded."""

    def __init__(self, elapsed: float = 0.0) -> None:
        self._start = time.perf_counter() - elapsed

    def seconds(self) -> float:
        return time.perf_counter() - self._start

    @contextmanager
    def paused(self) -> Iterator[None]:
        """The time spent in the ``with`` body does not count."""
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self._start += time.perf_counter() - t0
