"""An independent float64 quadrature of the emission-absorption integral: the plugin cases' reference.

Written again in numpy, sharing nothing with the package's sampling (``stratified_t``),
the render path's box clipping (``Box.intersect``, Dr.Jit) or compositing (``composite``), so a
bug there cannot reach it; the box is clipped by the float64 numpy slab test
``Box.intersect_numpy``, which only scoring uses besides. Only the field (the content under test's input, not its
quadrature) is evaluated
through Dr.Jit, at the same sample positions. Per ray, with ``[t_n, t_f]`` the ray's part of
the box ``[-0.5, 0.5]^3`` (docs/conventions.md) and ``h = (t_f - t_n) / N``::

    t_i     = t_n + (i + 1/2) h
    delta_i = t_{i+1} - t_i, delta_{N-1} = t_f - t_{N-1}     (rule "seed"), or h (rule "midpoint")
    T_i     = exp(-sum_{j<i} sigma_i delta_i),   C = sum_i T_i (1 - exp(-sigma_i delta_i)) c_i + T_N bg

>>> import numpy as np
>>> t_n, t_f, _ = UNIT_BOX.intersect_numpy(np.array([[0.0, 0.0, -2.0]]), np.array([[0.0, 0.0, 1.0]]))
>>> t_n, t_f
(array([1.5]), array([2.5]))
>>> t, delta = sample_distances(t_n, t_f, 4)
>>> t.tolist(), delta.tolist()
([[1.625, 1.875, 2.125, 2.375]], [[0.25, 0.25, 0.25, 0.125]])
>>> c = composite(np.full((1, 4), 2.0), np.full((1, 4), 0.25), np.ones((1, 4, 3)), np.zeros((1, 3)))
>>> round(float(c[0, 0]), 6)  # 1 - exp(-2)
0.864665
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from mitsnerf.math.box import UNIT_BOX


def sample_distances(
    t_n: np.ndarray, t_f: np.ndarray, n: int, quadrature: str = "seed"
) -> tuple[np.ndarray, np.ndarray]:
    """Stratum midpoints ``t`` (R, N) and interval lengths ``delta`` (R, N) of the rule ``quadrature``."""
    h = (t_f - t_n)[:, None] / n
    t = t_n[:, None] + (np.arange(n) + 0.5) * h
    if quadrature == "midpoint":
        return t, np.broadcast_to(h, t.shape).copy()
    if quadrature != "seed":
        raise ValueError(f"unknown quadrature {quadrature!r} (seed, midpoint)")
    ends = np.concatenate([t[:, 1:], t_f[:, None]], axis=1)
    return t, ends - t


def composite(sigma: np.ndarray, delta: np.ndarray, rgb: np.ndarray, background: np.ndarray) -> np.ndarray:
    """``C`` (R, 3) from ``sigma``, ``delta`` (R, N), colours ``rgb`` (R, N, 3) and the background (R, 3)."""
    tau = sigma * delta
    optical_depth = np.cumsum(tau, axis=1)
    T = np.exp(-(optical_depth - tau))  # exclusive prefix sum
    w = T * -np.expm1(-tau)
    return np.einsum("rn,rnc->rc", w, rgb) + np.exp(-optical_depth[:, -1])[:, None] * background


def environment_radiance(emitter, d: np.ndarray) -> np.ndarray:
    """Radiance (R, 3) of a Mitsuba environment emitter seen along directions ``d`` (R, 3); zero without one."""
    if emitter is None:
        return np.zeros((len(d), 3))
    import drjit as dr
    import mitsuba as mi

    si = dr.zeros(mi.SurfaceInteraction3f, len(d))
    si.wi = -mi.Vector3f(*np.asarray(d, dtype=np.float32).T)
    return np.stack([np.asarray(c, dtype=np.float64) for c in emitter.eval(si)], axis=-1)


def render(field: Callable[[Any, Any], tuple[Any, Any]], o: np.ndarray, d: np.ndarray, n: int,
           background: np.ndarray, quadrature: str = "seed") -> np.ndarray:
    """``C`` (R, 3) of rays ``o + t d`` through ``field`` (evaluated at float32 positions), float64 compositing."""
    import drjit as dr
    import mitsuba as mi

    t_n, t_f, _ = UNIT_BOX.intersect_numpy(o, d)
    t, delta = sample_distances(t_n, t_f, n, quadrature)
    x = (o[:, None, :] + t[..., None] * d[:, None, :]).reshape(-1, 3).astype(np.float32)
    dirs = np.repeat(np.asarray(d, dtype=np.float32), n, axis=0)
    with dr.suspend_grad():
        rgb, sigma = field(mi.Array3f(*x.T), mi.Array3f(*dirs.T))
    rgb_np = np.stack([np.asarray(c, dtype=np.float64) for c in rgb], axis=-1).reshape(len(o), n, 3)
    sigma_np = np.asarray(sigma, dtype=np.float64).reshape(len(o), n)
    return composite(sigma_np, delta, rgb_np, np.asarray(background, dtype=np.float64))
