"""The emission-absorption quadrature as one loop per ray: forward only, for fields a symbolic loop can call.

:func:`march_rays` computes exactly what :func:`mitsnerf.render.volume.render_rays` computes at
the stratum midpoints (the evaluation samples, the seed's rule)::

    t_i     = t_n + (i + 1/2) h,   h = (t_f - t_n) / N
    delta_i = t_{i+1} - t_i  (= h),   delta_{N-1} = t_f - t_{N-1}  (= h/2)
    C       = sum_i T_i (1 - exp(-sigma_i delta_i)) c_i + T_N bg,   T_i = exp(-sum_{j<i} sigma_j delta_j)

but inside one ``dr.while_loop`` over ``i``, so each ray's ``T``, colour and depth stay in registers
and nothing of size ``R * N`` is ever stored: one kernel instead of the sampler's, the field's and the
compositing's arrays. It needs a field whose evaluation is made of Dr.Jit array operations (grids
through ``dr.Texture3f``: the ground truth, ``voxel``'s grids, the oracle), not of tensors (the
networks), and it keeps no AD graph: for rendering views, not for training. ``render_rays`` stays the
reference the verification checks; a test holds the two equal.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import drjit as dr

from mitsnerf.math.box import Box
from mitsnerf.math.composite import Composite, channel_mean, one_minus_exp_neg
from mitsnerf.render.volume import background_radiance


def march_rays(field: Callable[[Any, Any], tuple[Any, Any]], o, d, n_samples: int, *, box: Box,
               background=None) -> Composite:
    """Render rays ``o + t d`` (Array3f (R,)) through ``field`` at the stratum midpoints, one loop per ray.

    A field with ``sigma_channels == 3`` (a chromatic grid, :class:`mitsnerf.fields.grid.GridField`) gives an
    Array3f ``sigma``, composited per channel as :func:`mitsnerf.math.composite.composite` does.

    Example: a homogeneous slab of ``sigma = 2`` seen along the z axis has opacity
    ``1 - exp(-2 * 15/16)`` with 8 samples, as :func:`render_rays`::

        >>> import mitsuba as mi
        >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
        >>> from mitsnerf.math.box import UNIT_BOX
        >>> slab = lambda x, d: (mi.Array3f(1.0) + 0 * x.x, mi.Float(2.0) + 0 * x.x)
        >>> march_rays(slab, mi.Array3f(0, 0, -2), mi.Array3f(0, 0, 1), 8, box=UNIT_BOX).opacity
        [0.846645]
    """
    if n_samples < 1:
        raise ValueError(f"march_rays: n_samples must be >= 1, got {n_samples}")
    Float = type(o.x)
    UInt32 = dr.uint32_array_t(Float)
    Array3f = type(o)
    with dr.suspend_grad():
        t_n, t_f, _ = box.intersect(o, d)
        span = t_f - t_n
        n = dr.opaque(UInt32, n_samples)
        tau_type = Array3f if getattr(field, "sigma_channels", 1) == 3 else Float
        state = (UInt32(0), dr.zeros(tau_type, dr.width(o)), dr.zeros(Array3f, dr.width(o)),
                 dr.zeros(tau_type, dr.width(o)))

        def body(i, tau, rgb, depth):
            fi = Float(i)
            t = t_n + (fi + 0.5) / n_samples * span
            t_next = dr.select(i + 1 == n, t_f, t_n + (fi + 1.5) / n_samples * span)
            delta = t_next - t
            c, sigma = field(o + t * d, d)
            w = dr.exp(-tau) * one_minus_exp_neg(sigma * delta)
            return i + 1, tau + sigma * delta, rgb + w * c, depth + w * t

        _, tau, rgb, depth = dr.while_loop(state, lambda i, *_: i < n, body, label="march_rays")
        T_final = dr.exp(-tau)
        rgb = rgb + T_final * background_radiance(background, d)
        return Composite(rgb=rgb, opacity=channel_mean(one_minus_exp_neg(tau)), depth=channel_mean(depth),
                         T_final=T_final)
