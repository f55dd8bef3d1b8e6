"""Loss monitoring: a non-finite loss stops training at once; a diverging one after a few log intervals.

Diverging means: the median loss of a log interval stays above ``factor`` times the lowest interval
median so far for ``patience`` intervals in a row. The median, not the mean: a Monte Carlo loss (a path
tracer's, a few samples per pixel) is heavy-tailed, and one step that meets a firefly can lift an
interval's mean tenfold while the fit goes on improving; a fit that diverges lifts every step's loss, and so
the median. The monitor's state is part of a checkpoint, so a resumed run's interval statistics and verdicts
are those of an uninterrupted run.

>>> m = LossMonitor(factor=10.0, patience=2)
>>> for loss in (1.0, 1.0):
...     m.add(loss)
>>> m.close_interval(), m.diverging
(1.0, False)
>>> for _ in range(2):
...     m.add(50.0); _ = m.close_interval()
>>> m.diverging
True
>>> m = LossMonitor(factor=10.0, patience=1)
>>> for interval in ([1.0, 1.0, 1.0], [1.0, 1.0, 500.0]):   # one firefly step: the mean 167, the median 1
...     for loss in interval:
...         m.add(loss)
...     mean = m.close_interval()
>>> mean, m.diverging
(167.33333333333334, False)
"""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass, field


@dataclass
class LossMonitor:
    factor: float
    """0: no divergence check."""
    patience: int
    best: float = math.inf
    """The lowest interval median so far."""
    bad: int = 0
    interval: list[float] = field(default_factory=list)
    """The losses of the interval since the last :meth:`close_interval`."""
    last_median: float = math.nan
    """The median of the last closed interval (nan before one closes, or without the check)."""

    def add(self, loss: float) -> None:
        self.interval.append(float(loss))

    def close_interval(self) -> float:
        """The mean loss of the interval since the last call (what the history logs); updates the divergence
        count from the interval's median."""
        losses = self.interval or [0.0]
        mean = math.fsum(losses) / len(losses)
        self.interval = []
        if self.factor:
            median = self.last_median = statistics.median(losses)
            self.bad = self.bad + 1 if median > self.factor * self.best else 0
            self.best = min(self.best, median)
        return mean

    def restart(self) -> None:
        """Forget the lowest median and the interval so far: the loss has changed meaning (a new objective stage).

        >>> m = LossMonitor(factor=10.0, patience=1)
        >>> m.add(1.0); _ = m.close_interval(); m.restart(); m.add(50.0); _ = m.close_interval()
        >>> m.diverging, m.best
        (False, 50.0)
        """
        self.best, self.bad, self.interval = math.inf, 0, []

    @property
    def diverging(self) -> bool:
        return bool(self.factor) and self.bad >= self.patience

    def healthy(self, loss: float) -> bool:
        """Whether a checkpoint of this step may replace the last good one."""
        return not self.factor or (self.bad == 0 and loss <= self.factor * self.best)

    def state(self) -> dict:
        return {"best": self.best if math.isfinite(self.best) else None, "bad": self.bad,
                "interval": list(self.interval)}

    def load_state(self, state: dict) -> None:
        """Restore :meth:`state` (a checkpoint written before the median kept the interval's sum and count only:
        its interval is taken as that many steps at their mean)."""
        best = state.get("best")
        self.best = math.inf if best is None else float(best)
        self.bad = int(state.get("bad", 0))
        if "interval" in state:
            self.interval = [float(v) for v in state["interval"]]
        else:
            n = int(state.get("interval_n", 0))
            self.interval = [float(state.get("interval_sum", 0.0)) / n] * n if n else []
