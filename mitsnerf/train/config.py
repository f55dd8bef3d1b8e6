"""How long and how to train: the budget is a number of optimiser steps.

Every schedule (the learning rate, a method's coarse-to-fine stages and occupancy updates) is a
function of the step alone, so the same config and seed train the same model whatever the
machine's load. ``seconds`` is an optional wall-clock cap for users who ask for one; a run it
stops records that its budget was time (``TrainResult.stopped_by``), and such a run is not
reproducible across machines.
"""

from __future__ import annotations

from dataclasses import dataclass

from mitsnerf.config import check_fields, param


@dataclass(frozen=True)
class TrainConfig:
    """Training settings shared by every method (the learning rate is the method's own ``lr``)."""

    steps: int = param(3000, lo=1, hi=10**8)
    """The budget: optimiser steps. Schedules follow ``step / steps``."""
    seconds: float = param(0.0, lo=0.0)
    """Optional wall-clock cap in seconds (0: none); training then stops at the first limit reached."""
    batch_rays: int = param(2048, lo=1, hi=1 << 22)
    """Rays per step (per-ray models)."""
    pixel_jitter: bool = param(True, since=("0.1.0+d886bdb", False))
    """Cast each training ray through a uniformly random point of its pixel (instant-ngp's rule),
    matching a box-filtered film; false: every ray through the pixel's sample point."""
    lr_final_factor: float = param(0.1, lo=0.0, hi=1.0, lo_open=True)
    """Exponential decay of the learning rate to ``lr * lr_final_factor`` at the last step."""
    seed: int = param(0, lo=0, hi=2**32 - 1)
    """Seed of the initialisation and of every step's random numbers (rays, jitter)."""
    log_every: int = param(25, lo=1)
    """Steps between progress-bar updates and history entries."""
    checkpoint_every: int = param(0, lo=0)
    """Steps between checkpoints (0: only at the end and when interrupted); needs a run directory."""
    divergence_factor: float = param(10.0, lo=0.0)
    """Diverging: the median loss of a log interval above this times its running minimum (0: no check)."""
    divergence_patience: int = param(3, lo=1)
    """Log intervals in a row above ``divergence_factor`` x minimum before training stops."""

    def __post_init__(self) -> None:
        check_fields(self)
        if self.divergence_factor != 0 and not self.divergence_factor > 1:
            raise ValueError(f"divergence_factor: must be 0 (off) or > 1, got {self.divergence_factor:g}")

    @property
    def budget(self) -> str:
        """How the run's length is set, for tables: ``"steps"``, or ``"steps or seconds"`` with a cap."""
        return "steps or seconds" if self.seconds else "steps"
