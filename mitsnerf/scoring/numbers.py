"""Scores as JSON numbers: a float or None (JSON has no NaN or infinity), and means that skip the missing."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


def finite(x) -> float | None:
    """``float(x)``, or None for None, NaN and infinities (JSON has no such numbers)."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def mean_of(values: Sequence[float | None]) -> float | None:
    """The mean of the values that are not None (None if there are none)."""
    vals = [v for v in values if v is not None]
    return float(np.mean(vals)) if vals else None
