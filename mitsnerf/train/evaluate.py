"""Evaluation of a trained model: what is rendered after (and during) training, and how.

Test views are rendered with the pixel footprint ``footprint`` (``K x K`` rays per pixel,
:func:`mitsnerf.render.camera.render_view`), so a model is measured as Mitsuba's box-filtered
film measured the ground truth; ``footprint = 1`` renders one ray through each pixel's sample
point (for foreign data made by point sampling). Every result records its ``footprint``.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from mitsnerf.config import check_fields, param
from mitsnerf.math.camera import Camera
from mitsnerf.methods.base import Model
from mitsnerf.render.camera import Rendered


@dataclass(frozen=True)
class EvalConfig:
    """What is measured besides training: after it, and (``curve_points``) during it."""

    footprint: int = param(3, lo=1, hi=16)
    """Rays per pixel side K: each test pixel is the mean of K x K stratified rays over its area
    (1: one ray through the pixel's sample point)."""
    curve_points: int = param(8, lo=0)
    """Held-out evaluations during training at steps k / curve_points of the budget (0: none);
    their time is kept off the training clock."""
    curve_views: int = param(0, lo=0)
    """Test views rendered at each curve point: the first N (0: all)."""
    psnr_targets: tuple[float, ...] = param((30.0, 35.0, 40.0), lo=0.0)
    """Medium-pixel PSNRs whose first crossing on the held-out curve is reported as seconds and steps."""
    density_resolution: int = param(0, lo=0)
    """Density error on an R^3 grid of voxel centres (0: the true grid's resolution; else >= 2)."""
    od_samples: int = param(0, lo=0)
    """Midpoint samples per test ray for the optical-depth error (0: twice the true grid's resolution)."""
    report_view: int = param(0, lo=0)
    """The test view shown in the image grid of the report."""
    train_eval_views: int = param(4, lo=0)
    """Training views scored after training (train PSNR, an overfitting check)."""

    def __post_init__(self) -> None:
        check_fields(self)
        if self.density_resolution == 1:
            raise ValueError(f"density_resolution: must be 0 (the true grid's) or >= 2, got {self.density_resolution}")


def render_views(model: Model, cameras: Sequence[Camera], *, pixel_center: float = 0.5,
                 footprint: int = 1) -> tuple[list[Rendered], float]:
    """Every camera rendered by ``model`` (its own :meth:`~mitsnerf.methods.base.Model.render_view`);
    returns the renders and the seconds they took."""
    start = time.perf_counter()
    renders = [model.render_view(cam, pixel_center=pixel_center, footprint=footprint) for cam in cameras]
    return renders, time.perf_counter() - start


def stack_rgb(renders: Sequence[Rendered]) -> np.ndarray:
    """(V, H, W, 3) float32 linear RGB of renders."""
    return np.stack([r.rgb for r in renders]).astype(np.float32)
