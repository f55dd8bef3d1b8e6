"""Pinhole cameras in the NeRF-synthetic (Blender/OpenGL) convention.

Camera-to-world ``c2w`` is a 4x4 matrix whose columns are the camera's x (right),
y (up) and z (backwards: the camera looks down -z) axes and its position, as in
``transforms_*.json``. Mitsuba's camera frame is [left, up, forward], so its
``to_world`` is ``c2w @ diag(-1, 1, -1, 1)`` (and back, the same product).

Pixel ``(col, row)`` covers ``[col, col+1) x [row, row+1)`` in image-plane
coordinates whose origin is the top-left corner of the image. Mitsuba renders
pixel centres at ``+0.5`` and so does every dataset mitsnerf writes
(``pixel_center = 0.5``). The original NeRF loader casts rays through the
integer corners (``pixel_center = 0.0``); choose that when reading data made so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

GL_TO_MITSUBA = np.diag([-1.0, 1.0, -1.0, 1.0])


@dataclass(frozen=True)
class Camera:
    """A pinhole camera: intrinsics in pixels and an OpenGL camera-to-world matrix.

    >>> cam = Camera.from_fov(np.eye(4), 4, 2, fov_x_deg=90.0)
    >>> round(cam.fl_x, 6), cam.cx, cam.cy
    (2.0, 2.0, 1.0)
    >>> o, d = cam.pixel_rays()
    >>> d[0].round(4).tolist()  # top-left pixel: left, up, forward (-z)
    [-0.5883, 0.1961, -0.7845]
    """

    c2w: np.ndarray = field(repr=False)
    width: int
    height: int
    fl_x: float
    fl_y: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        c2w = np.asarray(self.c2w, dtype=np.float64)
        if c2w.shape == (3, 4):
            c2w = np.vstack([c2w, [0.0, 0.0, 0.0, 1.0]])
        if c2w.shape != (4, 4) or not np.all(np.isfinite(c2w)):
            raise ValueError(f"camera c2w must be a finite 4x4 matrix, got shape {c2w.shape}")
        rot = c2w[:3, :3]
        if not np.allclose(rot.T @ rot, np.eye(3), atol=1e-4):
            raise ValueError("camera c2w rotation is not orthonormal (scaled or sheared camera)")
        if self.width < 1 or self.height < 1:
            raise ValueError(f"camera size must be positive, got {self.width}x{self.height}")
        if not (self.fl_x > 0 and self.fl_y > 0):
            raise ValueError(f"camera focal lengths must be positive, got {self.fl_x}, {self.fl_y}")
        c2w.setflags(write=False)
        object.__setattr__(self, "c2w", c2w)

    @classmethod
    def from_fov(cls, c2w, width: int, height: int, fov_x_deg: float) -> Camera:
        """Centred camera with horizontal field of view ``fov_x_deg`` (square pixels)."""
        if not 0.0 < fov_x_deg < 180.0:
            raise ValueError(f"fov_x must be in (0, 180) degrees, got {fov_x_deg}")
        fl = 0.5 * width / math.tan(0.5 * math.radians(fov_x_deg))
        return cls(c2w, width, height, fl, fl, 0.5 * width, 0.5 * height)

    @property
    def camera_angle_x(self) -> float:
        """Horizontal field of view in radians (the NeRF-synthetic key)."""
        return 2.0 * math.atan(0.5 * self.width / self.fl_x)

    @property
    def fov_x_deg(self) -> float:
        return math.degrees(self.camera_angle_x)

    @property
    def origin(self) -> np.ndarray:
        return self.c2w[:3, 3].copy()

    def mitsuba_to_world(self) -> np.ndarray:
        """Mitsuba sensor ``to_world`` (frame [left, up, forward]) for this camera."""
        return self.c2w @ GL_TO_MITSUBA

    def is_centred(self, tol: float = 1e-6) -> bool:
        return abs(self.cx - 0.5 * self.width) < tol and abs(self.cy - 0.5 * self.height) < tol

    def pixel_directions(self, cols, rows, pixel_center: float = 0.5) -> np.ndarray:
        """Unit world-space directions through image-plane points ``(cols + pixel_center, rows + pixel_center)``."""
        x = (np.asarray(cols, dtype=np.float64) + pixel_center - self.cx) / self.fl_x
        y = -(np.asarray(rows, dtype=np.float64) + pixel_center - self.cy) / self.fl_y
        d_cam = np.stack([x, y, -np.ones_like(x)], axis=-1)
        d = d_cam @ self.c2w[:3, :3].T
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def pixel_rays(self, pixel_center: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
        """Origins and unit directions of every pixel, row-major, each of shape (H*W, 3)."""
        rows, cols = np.meshgrid(np.arange(self.height), np.arange(self.width), indexing="ij")
        d = self.pixel_directions(cols.ravel(), rows.ravel(), pixel_center)
        o = np.broadcast_to(self.origin, d.shape).copy()
        return o, d

    def project(self, points: np.ndarray) -> np.ndarray:
        """Image-plane coordinates (col, row), shape (M, 2), of world points (M, 3) in front of the camera."""
        p = np.asarray(points, dtype=np.float64)
        w2c = np.linalg.inv(self.c2w)
        pc = p @ w2c[:3, :3].T + w2c[:3, 3]
        z = -pc[:, 2]
        return np.stack([self.cx + self.fl_x * pc[:, 0] / z, self.cy - self.fl_y * pc[:, 1] / z], axis=-1)


def look_at(origin, target=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """OpenGL camera-to-world matrix of a camera at ``origin`` looking at ``target``.

    >>> (look_at((0, -2, 0))[:3, 2] + 0.0).tolist()  # z points back, away from the target
    [0.0, -1.0, 0.0]
    """
    origin = np.asarray(origin, dtype=np.float64)
    forward = np.asarray(target, dtype=np.float64) - origin
    forward /= np.linalg.norm(forward)
    up = np.asarray(up, dtype=np.float64)
    if abs(float(np.dot(forward, up / np.linalg.norm(up)))) > 0.999:
        up = np.array([0.0, 1.0, 0.0]) if abs(forward[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    true_up = np.cross(right, forward)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, true_up, -forward, origin
    return c2w
