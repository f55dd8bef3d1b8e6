"""Whole camera views from a ray renderer, through pixel centres or integrating each pixel's footprint.

A *ray renderer* is any callable ``(o, d) -> Composite`` (:class:`mitsnerf.math.composite.Composite`)
on Array3f rays. :func:`render_view` renders every pixel of a camera with it. With ``footprint = K``
each pixel is the mean of ``K x K`` rays through the stratum centres of its footprint
(:func:`mitsnerf.math.rays.footprint_offsets`)::

    C_pixel = 1/K^2 sum_{a, b < K} C(ray through (col + pc - 1/2 + (a + 1/2)/K, row + pc - 1/2 + (b + 1/2)/K))

which converges to the box-filtered pixel Mitsuba's film records (``rfilter = box``) as K grows;
``K = 1`` is the single ray through the pixel's sample point (the pixel centre for ``pc = 0.5``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import drjit as dr
import numpy as np

from mitsnerf.math.camera import Camera
from mitsnerf.math.composite import Composite
from mitsnerf.math.rays import camera_rays_numpy, footprint_offsets, to_array3f

RayRenderer = Callable[[Any, Any], Composite]
"""``(o, d) -> Composite``: anything that renders a batch of rays."""


@dataclass(frozen=True)
class Rendered:
    """A rendered view: linear RGB (H, W, 3), opacity (H, W), depth (H, W; expected distance), float32."""

    rgb: np.ndarray
    opacity: np.ndarray
    depth: np.ndarray


def _render_rays_numpy(render: RayRenderer, o_np: np.ndarray, d_np: np.ndarray, chunk_rays: int) -> np.ndarray:
    """(M, 5) float64: rgb, opacity, depth of numpy rays, rendered in chunks without gradients."""
    import mitsuba as mi

    out = []
    with dr.suspend_grad():
        for start in range(0, len(o_np), chunk_rays):
            comp = render(to_array3f(mi.Array3f, o_np[start:start + chunk_rays]),
                          to_array3f(mi.Array3f, d_np[start:start + chunk_rays]))
            cols = [np.asarray(c, dtype=np.float64) for c in comp.rgb]
            cols += [np.asarray(comp.opacity, dtype=np.float64), np.asarray(comp.depth, dtype=np.float64)]
            out.append(np.stack(cols, axis=-1))
    return np.concatenate(out)


def render_view(render: RayRenderer, camera: Camera, *, pixel_center: float = 0.5, footprint: int = 1,
                chunk_rays: int = 1 << 14) -> Rendered:
    """Every pixel of ``camera`` rendered by ``render``, averaged over ``footprint x footprint`` rays.

    Example: a constant renderer gives a constant image whatever the footprint::

        >>> import mitsuba as mi
        >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
        >>> from mitsnerf.math.camera import look_at
        >>> flat = lambda o, d: Composite(mi.Array3f(0.25) + 0 * o.x, 0 * o.x, 0 * o.x, 1 + 0 * o.x)
        >>> view = render_view(flat, Camera.from_fov(look_at((0, -2, 0)), 3, 2, 40.0), footprint=2)
        >>> view.rgb.shape, float(view.rgb.max()), float(view.rgb.min())
        ((2, 3, 3), 0.25, 0.25)
    """
    total = np.zeros((camera.height * camera.width, 5))
    offsets = footprint_offsets(footprint)
    for du, dv in offsets:
        o, d = camera_rays_numpy([camera], pixel_center, (du, dv))
        total += _render_rays_numpy(render, o, d, chunk_rays)
    total /= len(offsets)
    shape = (camera.height, camera.width)
    return Rendered(total[:, :3].reshape(*shape, 3).astype(np.float32), total[:, 3].reshape(shape).astype(np.float32),
                    total[:, 4].reshape(shape).astype(np.float32))
