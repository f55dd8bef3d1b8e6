"""What a ray sees behind the medium: the radiance composited with ``T_N``.

Built from a dataset manifest's ``background`` description (see docs/conventions.md):
``{"type": "constant", "radiance": [r, g, b]}`` or
``{"type": "envmap", "file": ..., "to_world": 4x4, "scale": s}``, evaluated through
Mitsuba's own ``envmap`` emitter so the lookup is exactly what ``volpath`` saw.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import drjit as dr

from mitsnerf.errors import DatasetError


@dataclass(frozen=True)
class ConstantBackground:
    """The same radiance in every direction."""

    radiance: tuple[float, float, float]

    def __call__(self, d):
        return type(d)(*self.radiance)


@dataclass(frozen=True)
class EnvmapBackground:
    """Radiance of a Mitsuba ``envmap`` emitter in direction ``d`` (world space)."""

    emitter: Any

    def __call__(self, d):
        import mitsuba as mi

        si = dr.zeros(mi.SurfaceInteraction3f, dr.width(d))
        si.wi = -mi.Vector3f(d)
        return type(d)(self.emitter.eval(si))


def make_background(desc: Mapping[str, Any] | None, root: Path | None = None):
    """A callable ``d -> Array3f`` from a background description (None: black)."""
    if not desc:
        return ConstantBackground((0.0, 0.0, 0.0))
    kind = desc.get("type")
    if kind == "constant":
        rgb = desc.get("radiance", [0.0, 0.0, 0.0])
        if isinstance(rgb, (int, float)):
            rgb = [rgb] * 3
        if len(rgb) != 3:
            raise DatasetError(root, "background.radiance", f"needs 3 values, got {rgb!r}")
        r, g, b = (float(v) for v in rgb)
        return ConstantBackground((r, g, b))
    if kind == "envmap":
        import mitsuba as mi

        path = Path(desc["file"])
        if root is not None and not path.is_absolute():
            path = Path(root) / path
        if not path.exists():
            raise DatasetError(path, "background.file", "environment map not found")
        from mitsnerf.data.images import read_exr

        # The map is read here and handed over as a bitmap: Mitsuba's own EXR reader deadlocks once
        # Dr.Jit runs with one thread (dr.set_thread_count(1), as `bench --cpus-per-cell 1` does).
        emitter = mi.load_dict(
            {
                "type": "envmap",
                "bitmap": mi.Bitmap(read_exr(path)[..., :3]),
                "scale": float(desc.get("scale", 1.0)),
                "to_world": mi.ScalarTransform4f(
                    desc.get("to_world", [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
                ),
            }
        )
        return EnvmapBackground(emitter)
    raise DatasetError(root, "background.type", f"unknown background type {kind!r} (constant, envmap)")


def pixel_background(background, cameras, pixel_center: float = 0.5, footprint: int = 4):
    """What each pixel of ``cameras`` sees of ``background`` (a :func:`make_background` callable): float64
    ``(V, H, W, 3)``, the mean over ``footprint x footprint`` stratified points of the pixel (a box filter,
    as the film's).

    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> from mitsnerf.math.camera import Camera, look_at
    >>> cam = Camera.from_fov(look_at((0, 0, 3), (0, 0, 0), (0, 1, 0)), 2, 2, 40.0)
    >>> pixel_background(ConstantBackground((0.5, 0.25, 1.0)), [cam])[0, 1, 1].tolist()
    [0.5, 0.25, 1.0]
    """
    import mitsuba as mi
    import numpy as np

    from mitsnerf.math.rays import camera_rays_numpy, footprint_offsets, to_array3f

    shape = (len(cameras), cameras[0].height, cameras[0].width, 3)
    total = np.zeros((int(np.prod(shape[:3])), 3))
    offsets = footprint_offsets(footprint)
    for offset in offsets:
        _, d = camera_rays_numpy(cameras, pixel_center, tuple(offset))
        total += np.asarray(background(to_array3f(mi.Array3f, d)), dtype=np.float64).reshape(3, -1).T
    return (total / len(offsets)).reshape(shape)

