"""Evaluation of a trained model: what is rendered after (and during) training, and how.

Test views are rendered with the pixel footprint ``footprint`` (``K x K`` rays per pixel,
:func:`mitsnerf.render.camera.render_view`), so a model is measured as Mitsuba's box-filtered
film measured the ground truth; ``footprint = 1`` renders one ray through each pixel's sample
point (for foreign data made by point sampling). Every result records its ``footprint``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from mitsnerf.math.camera import Camera
from mitsnerf.methods.base import Model
from mitsnerf.render.camera import Rendered


@dataclass(frozen=True)
class EvalConfig:
    """What is measured besides training: after it, and (``curve_points``) during it."""

    footprint: int = 3
    """Rays per pixel side K: each test pixel is the mean of K x K stratified rays over its area
    (1: one ray through the pixel's sample point)."""
    curve_points: int = 8
    """Held-out evaluations during training at steps k / curve_points of the budget (0: none);
    their time is kept off the training clock."""
    curve_views: int = 0
    """Test views rendered at each curve point: the first N (0: all)."""
    psnr_targets: tuple[float, ...] = (30.0, 35.0, 40.0)
    """Medium-pixel PSNRs whose first crossing on the held-out curve is reported as seconds and steps."""
    density_resolution: int = 0
    """Density error on an R^3 grid of voxel centres (0: the true grid's resolution)."""
    od_samples: int = 0
    """Midpoint samples per test ray for the optical-depth error (0: twice the true grid's resolution)."""
    report_view: int = 0
    """The test view shown in the image grid of the report."""
    train_eval_views: int = 4
    """Training views scored after training (train PSNR, an overfitting check)."""

    def __post_init__(self) -> None:
        if not 1 <= self.footprint <= 16:
            raise ValueError(f"footprint: must be an integer in [1, 16], got {self.footprint}")
        for name in ("curve_points", "curve_views", "density_resolution", "od_samples", "report_view",
                     "train_eval_views"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name}: must be >= 0, got {getattr(self, name)}")
        if self.density_resolution and self.density_resolution < 2:
            raise ValueError(f"density_resolution: must be 0 (the true grid's) or >= 2, got {self.density_resolution}")
        object.__setattr__(self, "psnr_targets", tuple(float(t) for t in self.psnr_targets))


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
