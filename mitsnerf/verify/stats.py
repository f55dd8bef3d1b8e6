"""Statistics for comparing a deterministic rendering with a Monte Carlo reference.

The reference gives, per pixel and channel ``p``, the mean ``m_p`` of ``n`` independent
samples and their sample variance ``s_p^2``. The measured image ``x_p`` (our integrator:
deterministic) is tested against ``H0: E[m_p] = x_p`` with::

    se_p = sqrt(s_p^2 / n + f_p^2),     f_p = max(|m_p|, |x_p|) / n
    z_p  = (x_p - m_p) / se_p,          p_p = erfc(|z_p| / sqrt 2)     (two-sided)

``f_p`` is one sample's worth of the value (``1/n`` of it): where every one of the ``n``
samples was identical (a 0/1 delta-tracking estimate that never collided) the sample
variance is 0 although the true variance is not; an error below ``f_p`` cannot be resolved
from ``n`` samples (the "rule of three" bound for a never-seen event is ``3/n``).

Many pixels are tested at once, so the family-wise error rate ``alpha`` is held with Holm's
step-down procedure (uniformly more powerful than Bonferroni, same guarantee): with the
``m`` p-values sorted, ``p_(1) <= ... <= p_(m)``, reject ``H_(1) .. H_(k-1)`` where ``k`` is
the first index with ``p_(k) > alpha / (m - k + 1)``.

A per-pixel test has little power against a small error shared by every pixel (a biased
quadrature), so :func:`compare` also tests the image mean of each channel ``c``::

    z_mean_c = sum_p (x_pc - m_pc) / sqrt(sum_p se_pc^2)

(pixels are independent; the channels of one pixel are not -- they share the path -- so they
are tested separately, with Holm over the channels, rather than summed).

>>> round(two_sided_p(1.959964), 4)
0.05
>>> holm([0.001, 0.04, 0.03, 0.2], alpha=0.05).tolist()   # 0.001 <= 0.05/4; 0.03 > 0.05/3
[True, False, False, False]
>>> bonferroni([0.001, 0.04, 0.012], alpha=0.05).tolist()
[True, False, True]
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def two_sided_p(z) -> np.ndarray | float:
    """``P(|Z| >= |z|)`` for a standard normal ``Z``: ``erfc(|z| / sqrt 2)``."""
    z = np.abs(np.asarray(z, dtype=np.float64))
    p = np.vectorize(math.erfc, otypes=[np.float64])(z / math.sqrt(2.0)) if z.size else z
    return float(p) if np.ndim(p) == 0 else p


def holm(p_values, alpha: float) -> np.ndarray:
    """Holm-Bonferroni step-down rejections (boolean, same shape as ``p_values``)."""
    p = np.asarray(p_values, dtype=np.float64)
    flat = p.ravel()
    m = flat.size
    order = np.argsort(flat, kind="stable")
    thresholds = alpha / (m - np.arange(m))
    passed = flat[order] <= thresholds
    # Reject the sorted hypotheses before the first one that is not rejected.
    k = m if passed.all() else int(np.argmin(passed))
    reject = np.zeros(m, dtype=bool)
    reject[order[:k]] = True
    return reject.reshape(p.shape)


def bonferroni(p_values, alpha: float) -> np.ndarray:
    """Bonferroni rejections: ``p <= alpha / m``."""
    p = np.asarray(p_values, dtype=np.float64)
    return p <= alpha / max(p.size, 1)


def critical_z(alpha: float, m: int = 1) -> float:
    """``|z|`` above which Bonferroni over ``m`` two-sided tests rejects (bisection on erfc).

    >>> round(critical_z(0.05), 3), round(critical_z(0.01, 100), 3)
    (1.96, 3.891)
    """
    target = alpha / m
    lo, hi = 0.0, 40.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if math.erfc(mid / math.sqrt(2.0)) > target:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


@dataclass(frozen=True)
class Comparison:
    """A deterministic image against a Monte Carlo reference (see the module docstring)."""

    z: np.ndarray  # per pixel and channel
    rejected: np.ndarray  # Holm rejections, boolean, same shape
    z_means: np.ndarray  # z-statistic of the image mean, per channel (last axis)
    alpha: float
    rel_mean_error: float  # max over channels of |sum_p (x - m)| / sum_p |m|
    max_rel_error: float  # bound it is held to (inf: not held)

    @property
    def max_abs_z(self) -> float:
        return float(np.max(np.abs(self.z))) if self.z.size else 0.0

    @property
    def n_rejected(self) -> int:
        return int(self.rejected.sum())

    @property
    def z_mean(self) -> float:
        """The channel's image-mean z of largest magnitude."""
        return float(self.z_means[np.argmax(np.abs(self.z_means))]) if self.z_means.size else 0.0

    @property
    def mean_rejected(self) -> bool:
        return bool(holm(np.atleast_1d(two_sided_p(self.z_means)), self.alpha).any())

    @property
    def passed(self) -> bool:
        return self.n_rejected == 0 and not self.mean_rejected and self.rel_mean_error <= self.max_rel_error

    def summary(self) -> str:
        verdict = "pass" if self.passed else "FAIL"
        return (f"{verdict}: max|z| {self.max_abs_z:.2f}, {self.n_rejected}/{self.z.size} pixel tests rejected "
                f"(Holm, alpha {self.alpha:g}), image-mean z {self.z_mean:+.2f}, "
                f"relative error of the mean {self.rel_mean_error:.2e} (bound {self.max_rel_error:g})")


def compare(measured, mean, var, n: int, alpha: float, max_rel_error: float = math.inf) -> Comparison:
    """Test a deterministic image ``measured`` against a reference of ``n`` samples per pixel.

    ``measured``, ``mean``, ``var`` (the per-sample variance, not the variance of the mean)
    are arrays of one shape whose last axis is the channels, e.g. ``(H, W, 3)``.

    >>> m = np.full((4, 4, 3), 0.5); v = np.full_like(m, 0.25)
    >>> compare(m + 0.001, m, v, n=1024, alpha=0.01).passed      # 0.001 is 0.06 se
    True
    >>> c = compare(m + 0.02, m, v, n=1024, alpha=0.01)          # 1.3 se per pixel, 5 se in each mean
    >>> c.n_rejected, c.passed
    (0, False)
    """
    x = np.asarray(measured, dtype=np.float64)
    m = np.asarray(mean, dtype=np.float64)
    v = np.maximum(np.asarray(var, dtype=np.float64), 0.0)
    if not (x.shape == m.shape == v.shape):
        raise ValueError(f"shapes differ: measured {x.shape}, mean {m.shape}, var {v.shape}")
    if n < 2:
        raise ValueError(f"need at least 2 samples per pixel, got {n}")
    floor = np.maximum(np.abs(m), np.abs(x)) / n
    se2 = v / n + floor**2
    diff = x - m
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(se2 > 0, diff / np.sqrt(se2), np.where(diff == 0, 0.0, np.inf * np.sign(diff)))
    rejected = holm(two_sided_p(z), alpha)
    axes = tuple(range(x.ndim - 1))
    d_sum = diff.sum(axis=axes).reshape(-1)
    se_sum = np.sqrt(se2.sum(axis=axes)).reshape(-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        z_means = np.where(se_sum > 0, d_sum / se_sum, np.where(d_sum == 0, 0.0, np.inf * np.sign(d_sum)))
        scale = np.abs(m).sum(axis=axes).reshape(-1)
        rel = np.where(scale > 0, np.abs(d_sum) / scale, np.where(d_sum == 0, 0.0, np.inf))
    return Comparison(z, rejected, z_means, alpha, float(rel.max()), max_rel_error)
