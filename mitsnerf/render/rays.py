"""Rays: clipping against the scene box, and batches of camera rays as Dr.Jit arrays."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import drjit as dr
import numpy as np

from mitsnerf.math.camera import Camera

BOX_MIN = (-0.5, -0.5, -0.5)
BOX_MAX = (0.5, 0.5, 0.5)


def intersect_box(o, d, box_min=BOX_MIN, box_max=BOX_MAX):
    """Slab test: distances ``(t_n, t_f)`` where each ray ``o + t d`` enters and leaves the box.

    ``t_n`` is clamped to >= 0 (a ray starting inside the box begins at its origin).
    Rays that miss get ``t_n = t_f`` (an empty interval), so every sample on them has
    ``delta = 0`` and they composite to the background exactly. Shapes: o, d Array3f (R,)
    -> Float (R,), Float (R,), Bool (R,).

    >>> from drjit.llvm import Array3f
    >>> t_n, t_f, hit = intersect_box(Array3f(0, 0, -2), Array3f(0, 0, 1))
    >>> t_n, t_f, hit
    ([1.5], [2.5], [True])
    """
    Float = type(o.x)
    inv = dr.rcp(d)
    t0 = (dr.scalar.Array3f(box_min) - o) * inv
    t1 = (dr.scalar.Array3f(box_max) - o) * inv
    t_near = dr.max(dr.minimum(t0, t1))
    t_far = dr.min(dr.maximum(t0, t1))
    t_near = dr.maximum(t_near, 0.0)
    hit = t_far > t_near
    t_far = dr.select(hit, t_far, t_near)
    return Float(t_near), Float(t_far), hit


@dataclass(frozen=True)
class RayBatch:
    """Rays of one or many cameras, flattened view-major then row-major, as Dr.Jit Array3f (M,)."""

    o: Any
    d: Any

    @property
    def size(self) -> int:
        return dr.width(self.o)

    def take(self, index) -> "RayBatch":
        """The rays at ``index`` (UInt32 array)."""
        Array3f = type(self.o)
        return RayBatch(dr.gather(Array3f, self.o, index), dr.gather(Array3f, self.d, index))


def camera_rays_numpy(cameras: Sequence[Camera], pixel_center: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Origins and directions of every pixel of every camera, float32 arrays (V*H*W, 3)."""
    os_, ds = zip(*(cam.pixel_rays(pixel_center) for cam in cameras))
    return np.concatenate(os_).astype(np.float32), np.concatenate(ds).astype(np.float32)


def to_array3f(Array3f, values: np.ndarray):
    """A (M, 3) numpy array as a Dr.Jit Array3f of width M."""
    values = np.ascontiguousarray(values, dtype=np.float32)
    return Array3f(values[:, 0], values[:, 1], values[:, 2])


def camera_rays(Array3f, cameras: Sequence[Camera], pixel_center: float = 0.5) -> RayBatch:
    """All pixels of ``cameras`` as one :class:`RayBatch` of the given Array3f type."""
    o, d = camera_rays_numpy(cameras, pixel_center)
    return RayBatch(to_array3f(Array3f, o), to_array3f(Array3f, d))
