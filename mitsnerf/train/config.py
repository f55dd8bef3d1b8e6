"""How long and how to train: the budget is a number of optimiser steps.

Every schedule (the learning rate, a method's coarse-to-fine stages and occupancy updates) is a
function of the step alone, so the same config and seed train the same model whatever the
machine's load. ``seconds`` is an optional wall-clock cap for users who ask for one; a run it
stops records that its budget was time (``TrainResult.stopped_by``), and such a run is not
reproducible across machines.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class TrainConfig:
    """Training settings shared by every method (the learning rate is the method's own ``lr``)."""

    steps: int = 3000
    """The budget: optimiser steps. Schedules follow ``step / steps``."""
    seconds: float = 0.0
    """Optional wall-clock cap in seconds (0: none); training then stops at the first limit reached."""
    batch_rays: int = 2048
    """Rays per step (per-ray models)."""
    pixel_jitter: bool = True
    """Cast each training ray through a uniformly random point of its pixel (instant-ngp's rule),
    matching a box-filtered film; false: every ray through the pixel's sample point."""
    lr_final_factor: float = 0.1
    """Exponential decay of the learning rate to ``lr * lr_final_factor`` at the last step."""
    seed: int = 0
    log_every: int = 25
    """Steps between progress-bar updates and history entries."""
    checkpoint_every: int = 0
    """Steps between checkpoints (0: only at the end and when interrupted); needs a run directory."""
    divergence_factor: float = 10.0
    """Diverging: the mean loss of a log interval above this times its running minimum (0: no check)."""
    divergence_patience: int = 3
    """Log intervals in a row above ``divergence_factor`` x minimum before training stops."""

    def __post_init__(self) -> None:
        if not 1 <= self.steps <= 10**8:
            raise ValueError(f"steps: must be an integer in [1, 100000000], got {self.steps}")
        if self.seconds < 0:
            raise ValueError(f"seconds: must be >= 0, got {self.seconds}")
        if not 1 <= self.batch_rays <= 1 << 22:
            raise ValueError(f"batch_rays: must be an integer in [1, 4194304], got {self.batch_rays}")
        if not 0 < self.lr_final_factor <= 1:
            raise ValueError(f"lr_final_factor: must be in (0, 1], got {self.lr_final_factor}")
        if self.log_every < 1:
            raise ValueError(f"log_every: must be >= 1, got {self.log_every}")
        if self.checkpoint_every < 0:
            raise ValueError(f"checkpoint_every: must be >= 0, got {self.checkpoint_every}")
        if self.divergence_factor != 0 and not self.divergence_factor > 1:
            raise ValueError(f"divergence_factor: must be 0 (off) or > 1, got {self.divergence_factor}")
        if self.divergence_patience < 1:
            raise ValueError(f"divergence_patience: must be >= 1, got {self.divergence_patience}")

    @property
    def budget(self) -> str:
        """How the run's length is set, for tables: ``"steps"``, or ``"steps or seconds"`` with a cap."""
        return "steps or seconds" if self.seconds else "steps"
