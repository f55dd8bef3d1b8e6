"""Deliberately broken compositing steps: each verification case must fail on the ones it names.

Every mutation has the signature of :func:`mitsnerf.math.composite.composite`
(``(sigma, delta, rgb, n, background=0.0, t=None) -> Composite``) and is injected with
``render_rays(..., composite_fn=...)``. The correct quadrature is::

    T_i = exp(-sum_{j<i} sigma_j delta_j),   C = sum_i T_i (1 - exp(-sigma_i delta_i)) c_i + T_N bg

The mutations:

- ``off_by_one_T``: ``T_i = exp(-sum_{j<=i} sigma_j delta_j)`` (inclusive prefix sum); ``T_N`` right.
  Visible wherever c != 0; invisible with c = 0 (absorption only depends on ``T_N`` alone).
- ``delta_wrong_end``: ``delta_i = t_i - t_{i-1}`` with ``t_{-1} = t_n`` (each sample takes the
  interval *before* it). With stratum midpoints that is the per-ray rotation
  ``delta'_i = delta_{(i-1) mod N}``. Optical depth then errs by ``-(h/2) sigma_t(t_n)`` instead
  of ``-(h/2) sigma_t(t_f)``: visible where the density at entry and exit differ.
  Invisible in a furnace (the weights still sum to one) and for homogeneous media.
- ``no_background``: ``C = sum_i w_i c_i`` (the ``T_N bg`` term dropped).
- ``detach_T``: the right values, but ``T_i`` and ``T_N`` cut from the AD graph (a gradient bug).
- ``detach_rgb``: the right values, colour cut from the AD graph.

>>> import drjit as dr
>>> from drjit.llvm.ad import Float, Array3f
>>> out = delta_wrong_end(Float(1.0, 2.0), Float(0.25, 0.5), Array3f(1.0), 2)
>>> out.T_final   # exp(-(1 * 0.5 + 2 * 0.25)), the deltas swapped within the ray
[0.367879]
"""

from __future__ import annotations

import drjit as dr

from mitsnerf.math.composite import Composite, composite, one_minus_exp_neg


def _finish(sigma, delta, rgb, n, background, t, T, T_final) -> Composite:
    tau = sigma * delta
    w = T * one_minus_exp_neg(tau)
    color = dr.block_sum(w * rgb, n) + T_final * background
    opacity = 1.0 - T_final
    depth = dr.block_sum(w * t, n) if t is not None else dr.zeros(type(T_final), dr.width(T_final))
    return Composite(rgb=color, opacity=opacity, depth=depth, T_final=T_final)


def off_by_one_T(sigma, delta, rgb, n: int, background=0.0, t=None) -> Composite:
    """``T_i`` from the inclusive prefix sum ``exp(-sum_{j<=i} sigma_j delta_j)``."""
    tau = sigma * delta
    T = dr.exp(-dr.block_prefix_sum(tau, n, exclusive=False))
    T_final = dr.exp(-dr.block_sum(tau, n))
    return _finish(sigma, delta, rgb, n, background, t, T, T_final)


def delta_wrong_end(sigma, delta, rgb, n: int, background=0.0, t=None) -> Composite:
    """``delta_i = t_i - t_{i-1}``: each ray's deltas rotated by one, ``delta'_i = delta_{(i-1) mod N}``."""
    Float = type(delta)
    UInt32 = dr.uint32_array_t(Float)
    idx = dr.arange(UInt32, dr.width(delta))
    i = idx % n
    prev = dr.select(i == 0, idx + (n - 1), idx - 1)
    return composite(sigma, dr.gather(Float, delta, prev), rgb, n, background=background, t=t)


def no_background(sigma, delta, rgb, n: int, background=0.0, t=None) -> Composite:
    """The background term ``T_N bg`` dropped."""
    return composite(sigma, delta, rgb, n, background=0.0, t=t)


def detach_T(sigma, delta, rgb, n: int, background=0.0, t=None) -> Composite:
    """Correct values; ``T_i``, ``T_N`` detached from the AD graph (gradients only through alpha)."""
    tau = sigma * delta
    T = dr.detach(dr.exp(-dr.block_prefix_sum(tau, n, exclusive=True)))
    T_final = dr.detach(dr.exp(-dr.block_sum(tau, n)))
    return _finish(sigma, delta, rgb, n, background, t, T, T_final)


def detach_rgb(sigma, delta, rgb, n: int, background=0.0, t=None) -> Composite:
    """Correct values; the colour detached from the AD graph."""
    return composite(sigma, delta, dr.detach(rgb), n, background=background, t=t)


MUTATIONS = {
    "off_by_one_T": off_by_one_T,
    "delta_wrong_end": delta_wrong_end,
    "no_background": no_background,
    "detach_T": detach_T,
    "detach_rgb": detach_rgb,
}
"""Name -> broken compositing callable."""
