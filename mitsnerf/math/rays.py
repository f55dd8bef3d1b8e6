"""Camera rays: every pixel of a set of cameras, with a chosen point of the pixel, as numpy or Dr.Jit arrays.

A pixel ``(col, row)`` covers ``[col, col + 1) x [row, row + 1)`` of the image plane
(:mod:`mitsnerf.math.camera`). Its *sample point* is ``(col + pc, row + pc)`` with ``pc`` the
dataset's pixel centre (0.5 for Mitsuba and mitsnerf, 0 for the original NeRF loader). The
*footprint* of a pixel is the unit square centred on its sample point; offsets ``(du, dv)`` in
``[0, 1)^2`` address points of it::

    image point = (col + pc - 1/2 + du,  row + pc - 1/2 + dv)

``du = dv = 1/2`` is the sample point itself (one ray through the pixel centre), ``du, dv ~ U[0, 1)``
a jittered training ray (as instant-ngp casts them), and the ``K x K`` stratum centres
:func:`footprint_offsets` average the pixel as Mitsuba's box-filtered film does.

Rays are stored flat: view-major, then row-major (``index = (v H + row) W + col``).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import drjit as dr
import numpy as np

from mitsnerf.math.camera import Camera
from mitsnerf.math.composite import is_chromatic


def footprint_offsets(k: int) -> np.ndarray:
    """The ``K x K`` stratum centres of a pixel's footprint, float64 (K*K, 2) of ``(du, dv)``.

    >>> footprint_offsets(2).tolist()
    [[0.25, 0.25], [0.75, 0.25], [0.25, 0.75], [0.75, 0.75]]
    >>> footprint_offsets(1).tolist()
    [[0.5, 0.5]]
    """
    if k < 1:
        raise ValueError(f"footprint: K must be >= 1, got {k}")
    c = (np.arange(k) + 0.5) / k
    dv, du = np.meshgrid(c, c, indexing="ij")
    return np.stack([du.ravel(), dv.ravel()], axis=-1)


def camera_rays_numpy(cameras: Sequence[Camera], pixel_center: float = 0.5,
                      offset: tuple[float, float] = (0.5, 0.5)) -> tuple[np.ndarray, np.ndarray]:
    """Origins and unit directions of every pixel of every camera, float32 (V*H*W, 3).

    ``offset``: the point ``(du, dv)`` of each pixel's footprint (default its sample point).
    """
    shift = pixel_center - 0.5
    os_, ds = [], []
    for cam in cameras:
        rows, cols = np.meshgrid(np.arange(cam.height), np.arange(cam.width), indexing="ij")
        d = cam.pixel_directions(cols.ravel() + shift + offset[0], rows.ravel() + shift + offset[1], 0.0)
        os_.append(np.broadcast_to(cam.origin, d.shape))
        ds.append(d)
    return np.concatenate(os_).astype(np.float32), np.concatenate(ds).astype(np.float32)


def to_array3f(Array3f, values: np.ndarray):
    """A (M, 3) numpy array as a Dr.Jit Array3f of width M."""
    values = np.ascontiguousarray(values, dtype=np.float32)
    return Array3f(values[:, 0], values[:, 1], values[:, 2])


def host(v) -> np.ndarray:
    """A Dr.Jit Float (M,) as float64 ``(M,)``; an Array3f (say a chromatic extinction) as ``(M, 3)``.

    >>> from drjit.llvm import Array3f, Float
    >>> host(Float(1, 2)).shape, host(Array3f(Float(1, 2), 0, 0)).shape   # a constant channel is broadcast
    ((2,), (2, 3))
    """
    v = v + dr.zeros(type(v), dr.width(v))  # a constant (width 1) part is broadcast to the width
    if is_chromatic(v):
        return np.stack([np.asarray(v[k], np.float64) for k in range(3)], axis=-1)
    return np.asarray(v, np.float64)


@dataclass(frozen=True)
class RayBatch:
    """Rays as Dr.Jit Array3f (M,): origins ``o`` and unit directions ``d``."""

    o: Any
    d: Any

    @property
    def size(self) -> int:
        return dr.width(self.o)


def camera_rays(Array3f, cameras: Sequence[Camera], pixel_center: float = 0.5) -> RayBatch:
    """All pixels of ``cameras`` (through their sample points) as one :class:`RayBatch`."""
    o, d = camera_rays_numpy(cameras, pixel_center)
    return RayBatch(to_array3f(Array3f, o), to_array3f(Array3f, d))


class PixelRays:
    """Rays through any point of any pixel of a set of cameras, built in Dr.Jit from pixel indices.

    Holds each camera's origin, rotation and intrinsics as Dr.Jit arrays (one entry per
    camera), so a batch of pixels with offsets ``(du, dv)`` becomes rays without numpy::

        x_cam = (col + pc - 1/2 + du - cx) / fl_x,   y_cam = -(row + pc - 1/2 + dv - cy) / fl_y
        d     = normalise(R (x_cam, y_cam, -1)),     o = the camera's position

    >>> import numpy as np
    >>> from drjit.llvm import Float, UInt32
    >>> from mitsnerf.math.camera import Camera, look_at
    >>> cam = Camera.from_fov(look_at((0, -2, 0)), 4, 4, 60.0)
    >>> pix = PixelRays(Float, [cam])
    >>> o, d = pix.rays(UInt32(5), Float(0.5), Float(0.5))
    >>> ref = camera_rays_numpy([cam])[1][5]
    >>> bool(np.allclose(np.array(d).ravel(), ref, atol=1e-6))
    True
    """

    def __init__(self, Float, cameras: Sequence[Camera], pixel_center: float = 0.5) -> None:
        sizes = {(c.width, c.height) for c in cameras}
        if len(sizes) != 1:
            raise ValueError(f"PixelRays: every camera must have the same size, got {sorted(sizes)}")
        (self.width, self.height), = sizes
        self.n_views = len(cameras)
        self.Float = Float
        self.UInt32 = dr.uint32_array_t(Float)
        self.Array3f = sys.modules[Float.__module__].Array3f
        self.pixel_center = float(pixel_center)
        rot = np.stack([c.c2w[:3, :3] for c in cameras]).reshape(len(cameras), 9)
        self._rot = [Float(np.ascontiguousarray(rot[:, k], np.float32)) for k in range(9)]
        self._origin = self.Array3f(*(Float(np.array([c.origin[a] for c in cameras], np.float32)) for a in range(3)))
        self._intr = [
            Float(np.array([getattr(c, k) for c in cameras], np.float32)) for k in ("fl_x", "fl_y", "cx", "cy")
        ]

    @property
    def size(self) -> int:
        """Pixels in all: V * H * W."""
        return self.n_views * self.height * self.width

    def rays(self, index, du, dv):
        """``(o, d)`` Array3f of the pixels ``index`` (UInt32, flat view-major) at offsets ``(du, dv)``."""
        hw = self.height * self.width
        view = index // hw
        rest = index - view * hw
        row = rest // self.width
        col = rest - row * self.width
        fl_x, fl_y, cx, cy = (dr.gather(self.Float, a, view) for a in self._intr)
        shift = self.pixel_center - 0.5
        x = (self.Float(col) + shift + du - cx) / fl_x
        y = -(self.Float(row) + shift + dv - cy) / fl_y
        r = [dr.gather(self.Float, a, view) for a in self._rot]
        d = self.Array3f(r[0] * x + r[1] * y - r[2], r[3] * x + r[4] * y - r[5], r[6] * x + r[7] * y - r[8])
        return dr.gather(self.Array3f, self._origin, view), dr.normalize(d)


def fibonacci_directions(m: int) -> np.ndarray:
    """``m`` unit vectors (m, 3) spread evenly over the sphere (Fibonacci lattice).

    >>> d = fibonacci_directions(16)
    >>> d.shape, bool(np.allclose(np.linalg.norm(d, axis=1), 1)), bool(abs(d.mean(axis=0)).max() < 0.05)
    ((16, 3), True, True)
    """
    if m < 1:
        raise ValueError(f"directions: must be >= 1, got {m}")
    k = np.arange(m) + 0.5
    z = 1.0 - 2.0 * k / m
    phi = math.pi * (3.0 - math.sqrt(5.0)) * k
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)
