"""Emission-absorption compositing along rays (the quadrature of docs/conventions.md).

With samples ``i = 0 .. N-1`` of a ray (flat ray-major layout, see
:mod:`mitsnerf.math.sampling`)::

    alpha_i = 1 - exp(-sigma_i delta_i)
    T_i     = exp(-sum_{j<i} sigma_j delta_j)        (T_0 = 1)
    w_i     = T_i alpha_i
    C       = sum_i w_i c_i + T_N * background        (T_N = exp(-sum_i sigma_i delta_i))

All functions are differentiable with Dr.Jit AD (prefix and block sums carry
gradients) and work on any Dr.Jit array type.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import drjit as dr


def one_minus_exp_neg(tau):
    """``1 - exp(-tau)`` without float32 cancellation for small ``tau`` (Taylor below 1e-2).

    >>> from drjit.llvm import Float
    >>> one_minus_exp_neg(Float(1e-6, 1.0))  # doctest: +ELLIPSIS
    [1e-06, 0.6321...]
    """
    taylor = tau * (1.0 - tau * (0.5 - tau * (1.0 / 6.0)))
    return dr.select(tau < 1e-2, taylor, 1.0 - dr.exp(-tau))


def weights(sigma, delta, n: int):
    """Compositing weights ``w_i = T_i alpha_i`` (R*N,) and the final transmittance ``T_N`` (R,).

    The weights of a ray and its final transmittance sum to one.

    >>> from drjit.llvm import Float
    >>> w, T_final = weights(Float(1.0, 1.0), Float(1.0, 1.0), 2)
    >>> w  # doctest: +ELLIPSIS
    [0.6321..., 0.2325...]
    >>> T_final  # doctest: +ELLIPSIS
    [0.1353...]
    """
    tau = sigma * delta
    T = dr.exp(-dr.block_prefix_sum(tau, n, exclusive=True))
    w = T * one_minus_exp_neg(tau)
    T_final = dr.exp(-dr.block_sum(tau, n))
    return w, T_final


@dataclass(frozen=True)
class Composite:
    """What compositing a batch of rays gives, each entry of shape (R,)."""

    rgb: Any  # Array3f: sum_i w_i c_i + T_N * background
    opacity: Any  # Float: sum_i w_i = 1 - T_N (chromatic: the channels' mean)
    depth: Any  # Float: sum_i w_i t_i (expected termination distance, unnormalised; chromatic: the mean)
    T_final: Any  # Float: T_N (chromatic: Array3f, per channel)


def composite(sigma, delta, rgb, n: int, background=0.0, t=None) -> Composite:
    """Composite per-sample density and colour into per-ray colour.

    A chromatic medium's ``sigma`` is an Array3f, one extinction per colour channel: channel ``k`` of
    ``rgb`` and ``T_final`` is composited with ``sigma[k]`` alone, and ``opacity`` and ``depth`` are the
    channels' means (one map per view).

    Args:
        sigma: Float (R*N,), extinction ``sigma_t`` at the samples (>= 0); Array3f (R*N,) per channel.
        delta: Float (R*N,), interval lengths.
        rgb: Array3f (R*N,), colour (radiance) at the samples.
        n: samples per ray.
        background: colour seen through the medium (float, Array3f of shape (R,)).
        t: Float (R*N,) sample distances, for the depth output (optional).

    Example: a homogeneous slab ``sigma = 2`` of length 1, ``c = 1``, black background,
    has opacity ``1 - exp(-2)`` whatever N::

        >>> from drjit.llvm import Float, Array3f
        >>> out = composite(Float([2.0] * 4), Float([0.25] * 4), Array3f(1.0), 4)
        >>> out.opacity  # doctest: +ELLIPSIS
        [0.8646...]
        >>> out.rgb  # doctest: +ELLIPSIS
        [[0.8646..., 0.8646..., 0.8646...]]
    """
    w, T_final = weights(sigma, delta, n)
    color = dr.block_sum(w * rgb, n) + T_final * background
    opacity = one_minus_exp_neg(dr.block_sum(sigma * delta, n))
    depth = dr.block_sum(w * t, n) if t is not None else dr.zeros(type(T_final), dr.width(T_final))
    return Composite(rgb=color, opacity=channel_mean(opacity), depth=channel_mean(depth), T_final=T_final)


def is_chromatic(sigma) -> bool:
    """Whether ``sigma`` holds one extinction per colour channel (an Array3f) rather than one (a Float)."""
    return dr.depth_v(sigma) > 1


def channel_mean(v):
    """``v`` itself for a Float; the mean of its three channels for an Array3f (a chromatic ray's opacity, depth).

    >>> from drjit.llvm import Float, Array3f
    >>> channel_mean(Array3f(0.3, 0.6, 0.9)), channel_mean(Float(0.5))  # doctest: +ELLIPSIS
    ([0.6...], [0.5])
    """
    return (v[0] + v[1] + v[2]) * (1.0 / 3.0) if is_chromatic(v) else v
