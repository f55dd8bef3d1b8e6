"""Schedules as functions of the step alone, and the step's random numbers.

    lr(step) = lr_0 * f^(step / steps)        (exponential decay to lr_0 f at the end of the budget)

The generator of step ``k`` is seeded by ``(seed, k)`` alone, so a run resumed at step ``k``
draws exactly what an uninterrupted run would.

>>> learning_rate(1.0, 50, 100, 0.1)  # doctest: +ELLIPSIS
0.3162...
>>> learning_rate(1.0, 150, 100, 0.1)  # past the budget: the final rate
0.1
"""

from __future__ import annotations

import drjit as dr


def learning_rate(base_lr: float, step: int, steps: int, final_factor: float) -> float:
    """``base_lr * final_factor ** clip(step / steps, 0, 1)``."""
    return base_lr * final_factor ** min(max(step / steps, 0.0), 1.0)


def step_rng(seed: int, step: int):
    """The generator of step ``step``: a pure function of ``(seed, step)``."""
    return dr.rng(seed=(int(seed) & 0xFFFFFFFF) << 32 | (int(step) & 0xFFFFFFFF))
