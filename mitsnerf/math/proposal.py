"""Proposal sampling's training signal (mip-NeRF 360): proposal weights must bound the fine weights.

A proposal network's weights ``w^p`` over its intervals ``[s_k, s_{k+1}]`` (``K`` per ray) place the
fine samples; the fine pass's weights ``w_j`` over its own intervals ``[t_j, t_{j+1}]`` (``N`` per
ray) are what the proposal should predict. The proposal is trained so that on every fine interval
its *outer measure* bounds the fine weight from above::

    outer_j = sum of w^p_k over the proposal intervals that overlap [t_j, t_{j+1}]
            = P(k_hi(j)) - P(k_lo(j))       P(k) = sum_{k' < k} w^p_k'  (P(0) = 0, P(K) = total)
      k_lo = #{edges s_k <= t_j} - 1 (clipped to [0, K]),  k_hi = #{edges s_k < t_{j+1}} (clipped)
    L_prop = mean over rays of sum_j max(0, w_j - outer_j)^2 / (w_j + eps)

with the fine weights detached (the proposal follows the fine network, not the other way).
"""

from __future__ import annotations

import drjit as dr

from mitsnerf.math.sampling import count_before


def outer_measure(t_edges, n_t: int, s_edges, w_prop, n_s: int):
    """Per fine interval, the proposal weight of every proposal interval overlapping it: Float (R*n_t,).

    ``t_edges``: Float (R*(n_t+1),) increasing fine interval edges per ray; ``s_edges``: Float
    (R*(n_s+1),) proposal interval edges; ``w_prop``: Float (R*n_s,) proposal weights.

    Example: proposal weights 0.5 on [0, 1] and on [1, 2]; a fine interval inside the first
    proposal interval sees 0.5, one straddling both sees 1::

        >>> from drjit.llvm import Float
        >>> outer_measure(Float(0.2, 0.8, 1.5), 2, Float(0.0, 1.0, 2.0), Float(0.5, 0.5), 2)
        [0.5, 1]
    """
    Float = type(w_prop)
    UInt32 = dr.uint32_array_t(Float)
    n_rays = dr.width(w_prop) // n_s
    cdf = dr.block_prefix_sum(w_prop, n_s, exclusive=False)  # P(k + 1), k = 0 .. n_s - 1
    idx = dr.arange(UInt32, n_rays * n_t)
    ray = idx // n_t
    j = idx - ray * n_t
    lo_t = dr.gather(Float, t_edges, ray * (n_t + 1) + j)
    hi_t = dr.gather(Float, t_edges, ray * (n_t + 1) + j + 1)
    k_lo = count_before(s_edges, n_s + 1, lo_t, n_t, inclusive=True)  # edges <= t_j
    k_hi = count_before(s_edges, n_s + 1, hi_t, n_t, inclusive=False)  # edges < t_{j+1}
    k_lo = dr.clip(dr.select(k_lo > 0, k_lo - 1, 0), 0, n_s)
    k_hi = dr.clip(k_hi, 0, n_s)

    def P(k):  # noqa: N802  (the cumulative proposal weight before interval k)
        return dr.select(k > 0, dr.gather(Float, cdf, ray * n_s + dr.maximum(k, 1) - 1), 0.0)

    return dr.maximum(P(k_hi) - P(k_lo), 0.0)


def interlevel_loss(w_fine, t_edges, n_t: int, s_edges, w_prop, n_s: int, eps: float = 1e-7):
    """``mean over rays of sum_j max(0, w_j - outer_j)^2 / (w_j + eps)`` (module docstring), Float (1,).

    The fine weights are detached: gradients reach the proposal weights only.

    >>> from drjit.llvm import Float
    >>> interlevel_loss(Float(0.5, 0.0), Float(0.0, 1.0, 2.0), 2, Float(0.0, 1.0, 2.0), Float(0.5, 0.5), 2)
    [0]
    >>> interlevel_loss(Float(0.9, 0.0), Float(0.0, 1.0, 2.0), 2, Float(0.0, 1.0, 2.0), Float(0.5, 0.5), 2)
    [0.177778]
    """
    w = dr.detach(w_fine)
    outer = outer_measure(dr.detach(t_edges), n_t, dr.detach(s_edges), w_prop, n_s)
    excess = dr.maximum(w - outer, 0.0)
    n_rays = dr.width(w) // n_t
    return dr.sum(dr.square(excess) / (w + eps)) / n_rays
