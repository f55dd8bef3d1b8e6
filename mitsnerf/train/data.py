"""The training pixels: every pixel of every training view, its target colour, and how to cast a ray through it."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np

from mitsnerf.math.camera import Camera
from mitsnerf.math.rays import PixelRays, to_array3f


@dataclass(frozen=True)
class PixelData:
    """Training pixels: rays are built per step from pixel indices (:class:`PixelRays`), so they
    can pass through any point of their pixel; targets are an Array3f (P,) in the same order."""

    pixels: PixelRays
    rgb: Any
    """Array3f (P,): linear RGB of every pixel, view-major then row-major."""
    images: np.ndarray
    """The views themselves, (V, H, W, 3) linear RGB, for whole-view models."""
    cameras: tuple[Camera, ...]
    pixel_center: float = 0.5

    @classmethod
    def from_views(cls, images: np.ndarray, cameras: Sequence[Camera], pixel_center: float = 0.5) -> PixelData:
        """``images`` (V, H, W, 3) linear RGB with one camera each."""
        if len(images) != len(cameras):
            raise ValueError(f"{len(images)} images but {len(cameras)} cameras")
        pixels = PixelRays(mi.Float, cameras, pixel_center)
        return cls(pixels, to_array3f(mi.Array3f, np.asarray(images).reshape(-1, 3)), images, tuple(cameras),
                   pixel_center)

    @property
    def size(self) -> int:
        return self.pixels.size

    def batch(self, rng, n: int, jitter: bool):
        """``(o, d, target)`` of ``n`` pixels drawn uniformly with ``rng``; with ``jitter`` each ray
        passes through a uniformly random point of its pixel, else through its sample point."""
        idx = dr.minimum(mi.UInt32(rng.random(mi.Float, n) * self.size), self.size - 1)
        if jitter:
            du, dv = rng.random(mi.Float, n), rng.random(mi.Float, n)
        else:
            du = dv = mi.Float(0.5)
        o, d = self.pixels.rays(idx, du, dv)
        return o, d, dr.gather(mi.Array3f, self.rgb, idx)
