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

A per-pixel test has little power against a small error shared by every pixel (a biased
quadrature), so each channel ``c`` of the image mean is tested too::

    z_mean_c = sum_p (x_pc - m_pc) / sqrt(sum_p se_pc^2)

(pixels are independent; the channels of one pixel are not -- they share the path -- so they
are tested separately rather than summed). Where the measured image is itself an average of
``K`` random renders (the training path), its variance joins the reference's:
``se_p^2 = s_p^2 / n + v_p / K + f_p^2``.

One family per scenario. Every test of a scenario -- the pixel tests and the channel means of
each of its comparisons -- is one family, held at the family-wise error rate ``alpha`` by the
weighted Holm procedure (Holm 1979): hypothesis ``i`` has weight ``w_i`` (the channel means
share ``MEAN_SHARE`` of the total weight, the pixel tests the rest, equally within each
group); with the ``p_i / w_i`` sorted ascending, reject ``H_(1) .. H_(k-1)`` where ``k`` is the
first index with ``p_(k) > alpha w_(k) / sum_{j >= k} w_(j)``. Equal weights give Holm's
step-down procedure (uniformly more powerful than Bonferroni, same guarantee): reject
while ``p_(k) <= alpha / (m - k + 1)``. Giving the few mean tests half the weight keeps
their threshold near ``alpha / 6`` (|z| 3.8 at alpha 0.001) instead of ``alpha / (3P + 3)``.

>>> round(two_sided_p(1.959964), 4)
0.05
>>> holm([0.001, 0.04, 0.03, 0.2], alpha=0.05).tolist()   # 0.001 <= 0.05/4; 0.03 > 0.05/3
[True, False, False, False]
>>> weighted_holm([0.001, 0.04, 0.03, 0.2], [0.1, 0.1, 0.7, 0.1], alpha=0.05).tolist()  # 0.03 <= 0.05 * 0.7/0.9
[True, False, True, False]
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


def weighted_holm(p_values, weights, alpha: float) -> np.ndarray:
    """Weighted Holm step-down rejections (boolean, shape of ``p_values``); family-wise error <= ``alpha``.

    ``weights`` (positive, any scale) say how much of ``alpha`` each hypothesis may take.
    """
    p = np.asarray(p_values, dtype=np.float64)
    w = np.broadcast_to(np.asarray(weights, dtype=np.float64), p.shape).ravel()
    if np.any(w <= 0):
        raise ValueError("weighted_holm: weights must be positive")
    flat = p.ravel()
    m = flat.size
    order = np.argsort(flat / w, kind="stable")
    w_sorted = w[order]
    remaining = np.cumsum(w_sorted[::-1])[::-1]  # sum of the weights not yet rejected
    passed = flat[order] <= alpha * w_sorted / remaining
    # Reject the sorted hypotheses before the first one that is not rejected.
    k = m if passed.all() else int(np.argmin(passed))
    reject = np.zeros(m, dtype=bool)
    reject[order[:k]] = True
    return reject.reshape(p.shape)


def holm(p_values, alpha: float) -> np.ndarray:
    """Holm-Bonferroni step-down rejections (boolean, same shape as ``p_values``)."""
    return weighted_holm(p_values, 1.0, alpha)


def bonferroni(p_values, alpha: float) -> np.ndarray:
    """Bonferroni rejections: ``p <= alpha / m``."""
    p = np.asarray(p_values, dtype=np.float64)
    return p <= alpha / max(p.size, 1)


def ks_uniform(x) -> tuple[float, float]:
    """Kolmogorov-Smirnov test of ``x ~ U[0, 1)``: the statistic ``D`` and its p-value.

    ``D = sup |F_n(x) - x|``; ``p = Q((sqrt(n) + 0.12 + 0.11 / sqrt(n)) D)`` with
    ``Q(l) = 2 sum_{k >= 1} (-1)^{k-1} exp(-2 k^2 l^2)`` (Stephens' approximation, good for n >= 5).

    >>> d, p = ks_uniform((np.arange(1000) + 0.5) / 1000)   # evenly spread: D = 1/2000
    >>> round(d, 6), p
    (0.0005, 1.0)
    >>> ks_uniform(np.zeros(100))[1] < 1e-30                  # every sample at 0
    True
    """
    x = np.sort(np.asarray(x, dtype=np.float64).ravel())
    n = x.size
    if n < 5:
        raise ValueError(f"ks_uniform: need at least 5 values, got {n}")
    i = np.arange(1, n + 1)
    d = float(max(np.max(i / n - x), np.max(x - (i - 1) / n)))
    lam = (math.sqrt(n) + 0.12 + 0.11 / math.sqrt(n)) * d
    if lam < 0.2:
        return d, 1.0
    k = np.arange(1, 101)
    p = 2.0 * float(np.sum((-1.0) ** (k - 1) * np.exp(-2.0 * k**2 * lam**2)))
    return d, min(max(p, 0.0), 1.0)


def correlation_z(a, b) -> float:
    """``r sqrt(M)`` for the Pearson correlation ``r`` of ``M`` pairs: N(0, 1) when independent.

    A constant ``a`` or ``b`` (no variation at all) gives ``inf``: certainly not independent jitter.
    """
    a = np.asarray(a, dtype=np.float64).ravel()
    b = np.asarray(b, dtype=np.float64).ravel()
    sa, sb = a.std(), b.std()
    if sa == 0 or sb == 0:
        return math.inf
    r = float(np.mean((a - a.mean()) * (b - b.mean())) / (sa * sb))
    return r * math.sqrt(a.size)


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


MEAN_SHARE = 0.5
"""Share of a family's weight (so of its alpha) held by the channel-mean tests."""


@dataclass(frozen=True)
class ZTest:
    """One image against one Monte Carlo reference: z per pixel and channel, z of each channel mean."""

    label: str
    z: np.ndarray  # per pixel and channel
    z_means: np.ndarray  # per channel (last axis)
    rel_mean_error: float  # max over channels of |sum_p (x - m)| / sum_p |m|
    max_rel_error: float  # bound it is held to (inf: not held)

    @property
    def max_abs_z(self) -> float:
        return float(np.max(np.abs(self.z))) if self.z.size else 0.0

    @property
    def z_mean(self) -> float:
        """The channel-mean z of largest magnitude."""
        return float(self.z_means[np.argmax(np.abs(self.z_means))]) if self.z_means.size else 0.0

    @property
    def n_tests(self) -> int:
        return int(self.z.size + self.z_means.size)


def _z(diff, se2):
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(se2 > 0, diff / np.sqrt(se2), np.where(diff == 0, 0.0, np.inf * np.sign(diff)))


def z_test(measured, mean, var, n: int, *, measured_var=None, measured_n: int | None = None,
           max_rel_error: float = math.inf, label: str = "") -> ZTest:
    """The z-statistics of ``measured`` against a reference of ``n`` samples per pixel.

    ``measured``, ``mean``, ``var`` (the per-sample variance, not the variance of the mean)
    are arrays of one shape whose last axis is the channels, e.g. ``(H, W, 3)``. A measured
    image that is the mean of ``measured_n`` random renders passes their per-render
    variance as ``measured_var``.
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
    if measured_var is not None:
        if measured_n is None or measured_n < 2:
            raise ValueError(f"a measured variance needs measured_n >= 2, got {measured_n}")
        se2 = se2 + np.maximum(np.asarray(measured_var, dtype=np.float64), 0.0) / measured_n
    diff = x - m
    axes = tuple(range(x.ndim - 1))
    d_sum = diff.sum(axis=axes).reshape(-1)
    scale = np.abs(m).sum(axis=axes).reshape(-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(scale > 0, np.abs(d_sum) / scale, np.where(d_sum == 0, 0.0, np.inf))
    return ZTest(label, _z(diff, se2), _z(d_sum, se2.sum(axis=axes).reshape(-1)), float(rel.max()), max_rel_error)


@dataclass(frozen=True)
class Family:
    """The tests of one scenario, decided together at family-wise error rate ``alpha`` (weighted Holm)."""

    tests: tuple[ZTest, ...]
    alpha: float
    pixel_rejected: tuple[np.ndarray, ...]  # per test, boolean like its z
    mean_rejected: tuple[np.ndarray, ...]  # per test, boolean like its z_means

    @property
    def max_abs_z(self) -> float:
        return max(t.max_abs_z for t in self.tests)

    @property
    def z_mean(self) -> float:
        """The channel-mean z of largest magnitude over the family."""
        return max((t.z_mean for t in self.tests), key=abs)

    @property
    def rel_mean_error(self) -> float:
        """The largest relative error of an image mean over the family."""
        return max(t.rel_mean_error for t in self.tests)

    @property
    def n_rejected(self) -> int:
        return int(sum(r.sum() for r in self.pixel_rejected))

    @property
    def n_rejected_all(self) -> int:
        """Rejected tests of the whole family: pixels and channel means."""
        return self.n_rejected + int(sum(r.sum() for r in self.mean_rejected))

    @property
    def n_pixel_tests(self) -> int:
        return int(sum(t.z.size for t in self.tests))

    @property
    def n_tests(self) -> int:
        return int(sum(t.n_tests for t in self.tests))

    @property
    def mean_rejected_any(self) -> bool:
        return bool(any(r.any() for r in self.mean_rejected))

    @property
    def bounds_ok(self) -> bool:
        return all(t.rel_mean_error <= t.max_rel_error for t in self.tests)

    @property
    def passed(self) -> bool:
        return self.n_rejected == 0 and not self.mean_rejected_any and self.bounds_ok

    def summary(self) -> str:
        verdict = "pass" if self.passed else "FAIL"
        parts = [f"{verdict} (one family of {self.n_tests} tests, weighted Holm, alpha {self.alpha:g})"]
        for t, px, mr in zip(self.tests, self.pixel_rejected, self.mean_rejected):
            name = f"{t.label}: " if t.label else ""
            parts.append(f"{name}max|z| {t.max_abs_z:.2f}, {int(px.sum())}/{t.z.size} pixel tests rejected, "
                         f"channel-mean z {', '.join(f'{z:+.2f}' for z in t.z_means)}"
                         f"{' (rejected)' if mr.any() else ''}, relative error of the mean "
                         f"{t.rel_mean_error:.2e} (bound {t.max_rel_error:g})")
        return "; ".join(parts)


def decide(tests, alpha: float, mean_share: float = MEAN_SHARE) -> Family:
    """Decide ``tests`` (:class:`ZTest` s) as one family at family-wise error rate ``alpha``."""
    tests = tuple(tests)
    if not tests:
        raise ValueError("decide: no tests")
    if not 0.0 < mean_share < 1.0:
        raise ValueError(f"decide: mean_share must be in (0, 1), got {mean_share}")
    n_pixels = sum(t.z.size for t in tests)
    n_means = sum(t.z_means.size for t in tests)
    p = np.concatenate([np.ravel(two_sided_p(t.z)) for t in tests] + [np.ravel(two_sided_p(t.z_means)) for t in tests])
    w = np.concatenate([np.full(n_pixels, (1 - mean_share) / max(n_pixels, 1)),
                        np.full(n_means, mean_share / max(n_means, 1))])
    reject = weighted_holm(p, w, alpha)
    pixel_rejected, mean_rejected, at = [], [], 0
    for t in tests:
        pixel_rejected.append(reject[at:at + t.z.size].reshape(t.z.shape))
        at += t.z.size
    for t in tests:
        mean_rejected.append(reject[at:at + t.z_means.size].reshape(t.z_means.shape))
        at += t.z_means.size
    return Family(tests, alpha, tuple(pixel_rejected), tuple(mean_rejected))



def compare(measured, mean, var, n: int, alpha: float, max_rel_error: float = math.inf) -> Family:
    """Test a deterministic image ``measured`` against a reference of ``n`` samples per pixel (a family of one).

    >>> m = np.full((4, 4, 3), 0.5); v = np.full_like(m, 0.25)
    >>> compare(m + 0.001, m, v, n=1024, alpha=0.01).passed      # 0.001 is 0.06 se
    True
    >>> c = compare(m + 0.02, m, v, n=1024, alpha=0.01)          # 1.3 se per pixel, 5 se in each mean
    >>> c.n_rejected, c.passed
    (0, False)
    """
    return decide([z_test(measured, mean, var, n, max_rel_error=max_rel_error)], alpha)
