"""Render a trained model from dataset cameras and score it against the images."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import drjit as dr
import mitsuba as mi
import numpy as np

from mitsnerf.math.camera import Camera
from mitsnerf.math.composite import Composite
from mitsnerf.math.metrics import psnr, ssim
from mitsnerf.methods.base import Model
from mitsnerf.render.rays import camera_rays_numpy, to_array3f


@dataclass(frozen=True)
class Rendered:
    """A rendered view: linear RGB (H, W, 3), opacity (H, W), depth (H, W; expected distance)."""

    rgb: np.ndarray
    opacity: np.ndarray
    depth: np.ndarray


RenderFn = Callable[[Any, Any], Composite]
"""``(o, d) -> Composite``: anything that renders a batch of rays."""


def model_renderer(model: Model) -> RenderFn:
    """The deterministic (midpoint-sample) renderer of a trained model."""
    return lambda o, d: model.render_rays(o, d, u=None, training=False).composite


def render_camera(render: RenderFn | Model, camera: Camera, chunk_rays: int = 1 << 14, pixel_center: float = 0.5) -> Rendered:
    """Render every pixel of ``camera`` with ``render`` (a :data:`RenderFn` or a model).

    A model that renders whole cameras itself (:meth:`Model.render_view` not None) does so.
    """
    if isinstance(render, Model):
        own = render.render_view(camera, pixel_center=pixel_center)
        if own is not None:
            return own
        render = model_renderer(render)
    o_np, d_np = camera_rays_numpy([camera], pixel_center)
    rgb, opacity, depth = [], [], []
    with dr.suspend_grad():
        for start in range(0, len(o_np), chunk_rays):
            o = to_array3f(mi.Array3f, o_np[start:start + chunk_rays])
            d = to_array3f(mi.Array3f, d_np[start:start + chunk_rays])
            comp = render(o, d)
            rgb.append(np.stack([np.asarray(c, dtype=np.float32) for c in comp.rgb], axis=-1))
            opacity.append(np.asarray(comp.opacity, dtype=np.float32))
            depth.append(np.asarray(comp.depth, dtype=np.float32))
    shape = (camera.height, camera.width)
    return Rendered(
        np.concatenate(rgb).reshape(*shape, 3),
        np.concatenate(opacity).reshape(shape),
        np.concatenate(depth).reshape(shape),
    )


@dataclass
class EvalResult:
    """Per-view and mean scores of one split (linear RGB, clipped to [0, 1])."""

    psnr: list[float]
    ssim: list[float]
    seconds: float
    renders: list[Rendered] = field(default_factory=list, repr=False)

    @property
    def psnr_mean(self) -> float:
        return float(np.mean(self.psnr))

    @property
    def ssim_mean(self) -> float:
        return float(np.mean(self.ssim))


def evaluate_views(
    model: Model,
    images: np.ndarray,
    cameras: Sequence[Camera],
    *,
    pixel_center: float = 0.5,
    keep_renders: bool = True,
) -> EvalResult:
    """Render each camera and compare with its image (V, H, W, 3): PSNR and SSIM per view."""
    start = time.perf_counter()
    scores_psnr, scores_ssim, renders = [], [], []
    for image, camera in zip(images, cameras):
        out = render_camera(model, camera, pixel_center=pixel_center)
        pred = np.clip(out.rgb, 0.0, 1.0)
        ref = np.clip(image, 0.0, 1.0)
        scores_psnr.append(float(psnr(pred, ref)))
        scores_ssim.append(float(ssim(pred, ref)))
        if keep_renders:
            renders.append(out)
    return EvalResult(scores_psnr, scores_ssim, time.perf_counter() - start, renders)
