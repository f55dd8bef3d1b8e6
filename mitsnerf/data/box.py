"""Where a dataset's scene box comes from, in order of precedence.

1. an explicit box (``mitsnerf train --box``), or an ``aabb`` key ``[[x0, y0, z0], [x1, y1, z1]]``
   in the transforms file;
2. mitsnerf's own datasets: the manifest's ``box`` (datasets older than format 4 have a
   ``spec`` and the unit box ``[-0.5, 0.5]^3``);
3. instant-ngp's convention, when the transforms have ``aabb_scale`` (with ``scale``, default
   0.33, and ``offset``, default ``[0.5, 0.5, 0.5]``): instant-ngp maps a world point ``p`` to
   ``q = cycle(p * scale + offset)`` and renders the cube ``q in [0.5 - a/2, 0.5 + a/2]^3``
   (``a = aabb_scale``), so the world box is ``(0.5 -+ a/2 - offset) / scale`` per axis;
4. plain NeRF-synthetic data: nerfstudio's blender default ``[-1.5, 1.5]^3``.

The source is recorded with the box (:class:`ResolvedBox`) and said in the output of
``mitsnerf train``. A box whose cameras all lie inside it is refused: the scene must be seen
from outside.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mitsnerf.errors import CLI, DatasetError, Words
from mitsnerf.math.box import UNIT_BOX, Box

NERF_SYNTHETIC_BOX = Box.cube(1.5)
"""nerfstudio's blender dataparser default, and where the original NeRF-synthetic scenes fit."""
NGP_DEFAULT_SCALE = 0.33
NGP_DEFAULT_OFFSET = (0.5, 0.5, 0.5)


@dataclass(frozen=True)
class ResolvedBox:
    box: Box
    source: str
    """Where it came from, e.g. ``"transforms_train.json: aabb"`` or ``"default: nerfstudio blender [-1.5, 1.5]^3"``."""


def _parse_box(value: Any, where: Path | str | None, field: str) -> Box:
    try:
        return Box.from_list(value)
    except ValueError as exc:
        raise DatasetError(where, field, str(exc).removeprefix("box: ")) from None


def _positive(value: Any, where: Path | str | None, field: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
        raise DatasetError(where, field, f"must be a positive number, got {value!r}")
    return float(value)


def ngp_box(doc: Mapping[str, Any], where: Path | str | None = None) -> Box:
    """The world box of instant-ngp's ``aabb_scale``, ``scale`` and ``offset`` keys (module docstring).

    >>> ngp_box({"aabb_scale": 1}).lo  # doctest: +ELLIPSIS
    (-1.515..., -1.515..., -1.515...)
    """
    offset = doc.get("offset", NGP_DEFAULT_OFFSET)
    a, scale = (_positive(doc.get(f, d), where, f) for f, d in (("aabb_scale", None), ("scale", NGP_DEFAULT_SCALE)))
    off = np.asarray(offset, dtype=np.float64) if isinstance(offset, (list, tuple)) else np.full(3, np.nan)
    if off.shape != (3,) or not np.all(np.isfinite(off)):
        raise DatasetError(where, "offset", f"must be 3 finite numbers, got {offset!r}")
    lo = (0.5 - 0.5 * a - off) / scale
    hi = (0.5 + 0.5 * a - off) / scale
    return Box(tuple(lo), tuple(hi))


def resolve_box(explicit: Box | None, transforms: Mapping[str, Any], transforms_path: Path,
                manifest: Mapping[str, Any] | None, manifest_path: Path, words: Words = CLI) -> ResolvedBox:
    """The dataset's box by the module docstring's rules (``words``: how the source of a given box is named)."""
    name = transforms_path.name
    if explicit is not None:
        return ResolvedBox(explicit, f"given explicitly ({words.name('box')})")
    if "aabb" in transforms:
        return ResolvedBox(_parse_box(transforms["aabb"], transforms_path, "aabb"), f"{name}: aabb")
    if manifest:
        if "box" in manifest:
            return ResolvedBox(_parse_box(manifest["box"], manifest_path, "box"), "manifest.json: box")
        if "spec" in manifest:
            return ResolvedBox(UNIT_BOX, "manifest.json: spec (mitsnerf's unit box)")
    if "aabb_scale" in transforms:
        return ResolvedBox(ngp_box(transforms, transforms_path), f"{name}: instant-ngp aabb_scale/scale/offset")
    return ResolvedBox(NERF_SYNTHETIC_BOX, "default for NeRF-synthetic data: nerfstudio's blender box [-1.5, 1.5]^3")


def check_cameras_outside(box: Box, origins: Sequence[np.ndarray], where: Path | str | None, source: str,
                          words: Words = CLI) -> None:
    """Refuse a box that contains every camera: nothing would be seen from outside the medium (the advice in
    ``words``, :class:`mitsnerf.errors.Words`)."""
    inside = box.contains(np.asarray(origins, dtype=np.float64).reshape(-1, 3))
    if len(inside) and bool(np.all(inside)):
        raise DatasetError(where, "frames[*].transform_matrix",
                           f"every camera lies inside the scene box {box.to_list()} ({source}); "
                           f"give a smaller box ({words.name('box')}, or an 'aabb' key) or check the camera poses")


#: What ``mitsnerf train`` says of near and far: no fixed pair (NeRF-synthetic readers use 2 and 6), each ray's own.
NEAR_FAR_RULE = "each ray's t_n, t_f where it enters and leaves the box (slab test, t_n >= 0)"


def near_far_range(box: Box, cameras: Sequence, pixel_center: float = 0.5,
                   n: int = 9) -> tuple[float, float, float, float, int, int]:
    """``(t_n min, t_n max, t_f min, t_f max, misses, rays)`` of the rule :data:`NEAR_FAR_RULE` (the
    interval every method samples, :meth:`mitsnerf.math.box.Box.intersect`) over an ``n x n`` grid of
    each camera's pixels, corners included; the ranges are over the rays that hit the box (NaN if none).

    >>> from mitsnerf.math.camera import Camera, look_at
    >>> cam = Camera.from_fov(look_at((0.0, 0.0, 4.0)), 8, 8, 20.0)
    >>> [round(v, 3) for v in near_far_range(Box.cube(1.5), [cam])[:4]]  # faces z = 1.5, -1.5; corner rays x 1.031
    [2.5, 2.577, 5.5, 5.668]
    """
    o, d = [], []
    for cam in cameras:
        cols = np.linspace(0.0, cam.width, n)
        rows = np.linspace(0.0, cam.height, n)
        grid_c, grid_r = np.meshgrid(cols, rows)
        d.append(cam.pixel_directions(grid_c.ravel(), grid_r.ravel(), 0.0))
        o.append(np.broadcast_to(cam.origin, d[-1].shape))
    t_n, t_f, hit = box.intersect_numpy(np.concatenate(o), np.concatenate(d))
    if not hit.any():
        return (math.nan,) * 4 + (int(hit.size), int(hit.size))
    return (float(t_n[hit].min()), float(t_n[hit].max()), float(t_f[hit].min()), float(t_f[hit].max()),
            int((~hit).sum()), int(hit.size))
