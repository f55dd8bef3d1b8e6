"""Empty space seen by the training views: an emptiness mask (space carving).

A training pixel whose value is the environment seen straight through, ::

    max over channels |I(p) - background(d_p)| <= tol        (d_p: the pixel centre ray's direction)

says that no medium lies along its ray (in a rendered dataset such pixels are exact: every sample of their
footprint missed the medium). Every voxel of an ``R^3`` grid over the scene box that such a ray crosses is then
empty; the others are kept. A method multiplies its density by the mask, so no haze can grow where the views
show none, and its occupancy grid skips those cells from the first update on.

>>> import numpy as np
>>> from mitsnerf.math.box import UNIT_BOX
>>> from mitsnerf.math.camera import Camera, look_at
>>> cam = Camera.from_fov(look_at((0.0, 0.0, -3.0)), 4, 4, fov_x_deg=20.0)   # the box fills its view
>>> int(carve_mask([cam], [np.ones(16, dtype=bool)], UNIT_BOX, 4).sum())    # every pixel background: all carved
0
>>> one = np.zeros(16, dtype=bool); one[0] = True                           # one corner pixel background
>>> int(carve_mask([cam], [one], UNIT_BOX, 4).sum())                        # its ray's 4 voxels carved
60
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from mitsnerf.math.box import Box
from mitsnerf.math.rays import camera_rays_numpy

RAYS_PER_CHUNK = 1 << 14
"""Rays carved at once (bounds the points held in memory: ``RAYS_PER_CHUNK`` x ``2 sqrt(3) R``)."""


def unattenuated_pixels(images: np.ndarray, cameras: Sequence[Any], background: Callable[[Any], Any], tol: float,
                        pixel_center: float = 0.5) -> list[np.ndarray]:
    """Per view, the pixels (H W,) bool whose value is the environment seen straight through:
    ``max over channels |image - background(d)| <= tol``, ``d`` the pixel centre ray's direction.

    ``images``: (V, H, W, 3) linear RGB, one camera each; ``background``: ``d -> Array3f`` (Mitsuba vectors)."""
    import mitsuba as mi

    out = []
    for img, cam in zip(images, cameras):
        _, d = camera_rays_numpy([cam], pixel_center)
        bg = np.asarray(background(mi.Vector3f(*(np.ascontiguousarray(d[:, k]) for k in range(3)))))
        bg = bg.reshape(3, -1).T  # (H W, 3), or (1, 3) for a constant background
        out.append(np.abs(np.asarray(img, np.float64).reshape(-1, 3) - bg).max(axis=1) <= tol)
    return out


def carve_mask(cameras: Sequence[Any], empty: Sequence[np.ndarray], box: Box, resolution: int,
               pixel_center: float = 0.5) -> np.ndarray:
    """Voxels (R, R, R) ``[z, y, x]`` to keep: False where the centre ray of an ``empty`` pixel passes (its
    points every half voxel along the chord ``[t_n, t_f]``, each in the voxel that holds it); ``empty``: one
    (H W,) bool per camera (:func:`unattenuated_pixels`)."""
    r = int(resolution)
    keep = np.ones((r, r, r), dtype=bool)
    lo, size = np.asarray(box.lo, np.float64), np.asarray(box.size, np.float64)
    n = int(np.ceil(2 * np.sqrt(3.0) * r)) + 1
    u = (np.arange(n) + 0.5) / n
    for cam, e in zip(cameras, empty):
        o, d = camera_rays_numpy([cam], pixel_center)
        t_n, t_f, hit = box.intersect_numpy(o, d)
        rays = np.flatnonzero(hit & np.asarray(e, bool))
        for start in range(0, rays.size, RAYS_PER_CHUNK):
            sel = rays[start:start + RAYS_PER_CHUNK]
            t = t_n[sel, None] + u[None] * (t_f - t_n)[sel, None]
            p = o[sel, None].astype(np.float64) + t[..., None] * d[sel, None].astype(np.float64)
            idx = np.clip(((p - lo) / size * r).astype(np.int64), 0, r - 1).reshape(-1, 3)
            keep[idx[:, 2], idx[:, 1], idx[:, 0]] = False
    return keep


def carve(images: np.ndarray, cameras: Sequence[Any], background: Callable[[Any], Any], box: Box, resolution: int,
          tol: float, pixel_center: float = 0.5) -> np.ndarray:
    """The emptiness mask (R, R, R) bool of the views (:func:`unattenuated_pixels`, then :func:`carve_mask`)."""
    empty = unattenuated_pixels(images, cameras, background, tol, pixel_center)
    return carve_mask(cameras, empty, box, resolution, pixel_center)


def pooled_mask(keep: np.ndarray, resolution: int) -> np.ndarray:
    """A fine mask ``keep`` (R, R, R) at a coarser ``resolution`` r dividing R: a coarse voxel is kept where any
    of its ``(R / r)^3`` fine voxels is, so no voxel a finer grid keeps is carved at the coarse one (a coarse
    voxel crossed by one empty ray is not empty).

    >>> keep = np.zeros((4, 4, 4), bool); keep[0, 0, 1] = True
    >>> pooled_mask(keep, 2)[0, 0, 0], int(pooled_mask(keep, 2).sum())
    (np.True_, 1)
    """
    big = keep.shape[0]
    if big % resolution:
        raise ValueError(f"pooled_mask: {resolution} does not divide {big}")
    k = big // resolution
    return np.asarray(keep.reshape(resolution, k, resolution, k, resolution, k).any(axis=(1, 3, 5)))


def carve_levels(images: np.ndarray, cameras: Sequence[Any], background: Callable[[Any], Any], box: Box,
                 resolutions: Sequence[int], tol: float, pixel_center: float = 0.5) -> dict[int, np.ndarray]:
    """The emptiness mask of every resolution of a coarse-to-fine grid: the finest carved once (:func:`carve`),
    each coarser one that divides it pooled from it (:func:`pooled_mask`), any other carved on its own."""
    finest = max(resolutions)
    keep = carve(images, cameras, background, box, finest, tol, pixel_center)
    return {r: pooled_mask(keep, r) if finest % r == 0 else carve(images, cameras, background, box, r, tol,
                                                                  pixel_center) for r in resolutions}
