"""Loss monitoring: a non-finite loss stops training at once; a diverging one after a few log intervals.

Diverging means: the mean loss of a log interval stays above ``factor`` times the lowest interval
mean so far for ``patience`` intervals in a row. The monitor's state is part of a checkpoint, so
a resumed run's interval means and verdicts are those of an uninterrupted run.

>>> m = LossMonitor(factor=10.0, patience=2)
>>> for loss in (1.0, 1.0):
...     m.add(loss)
>>> m.close_interval(), m.diverging
(1.0, False)
>>> for _ in range(2):
...     m.add(50.0); _ = m.close_interval()
>>> m.diverging
True
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass
class LossMonitor:
    factor: float
    """0: no divergence check."""
    patience: int
    best: float = math.inf
    bad: int = 0
    interval_sum: float = 0.0
    interval_n: int = 0

    def add(self, loss: float) -> None:
        self.interval_sum += loss
        self.interval_n += 1

    def close_interval(self) -> float:
        """The mean loss of the interval since the last call; updates the divergence count."""
        mean = self.interval_sum / max(self.interval_n, 1)
        self.interval_sum, self.interval_n = 0.0, 0
        if self.factor:
            self.bad = self.bad + 1 if mean > self.factor * self.best else 0
            self.best = min(self.best, mean)
        return mean

    def restart(self) -> None:
        """Forget the lowest mean and the interval so far: the loss has changed meaning (a new objective stage).

        >>> m = LossMonitor(factor=10.0, patience=1)
        >>> m.add(1.0); _ = m.close_interval(); m.restart(); m.add(50.0); _ = m.close_interval()
        >>> m.diverging, m.best
        (False, 50.0)
        """
        self.best, self.bad, self.interval_sum, self.interval_n = math.inf, 0, 0.0, 0

    @property
    def diverging(self) -> bool:
        return bool(self.factor) and self.bad >= self.patience

    def healthy(self, loss: float) -> bool:
        """Whether a checkpoint of this step may replace the last good one."""
        return not self.factor or (self.bad == 0 and loss <= self.factor * self.best)

    def state(self) -> dict:
        return {"best": self.best if math.isfinite(self.best) else None, "bad": self.bad,
                "interval_sum": self.interval_sum, "interval_n": self.interval_n}

    def load_state(self, state: dict) -> None:
        best = state.get("best")
        self.best = math.inf if best is None else float(best)
        self.bad = int(state.get("bad", 0))
        self.interval_sum = float(state.get("interval_sum", 0.0))
        self.interval_n = int(state.get("interval_n", 0))
