"""What every volume family shares: the grid pair it returns, its registry record, voxel geometry.

Grid geometry (docs/conventions.md): voxel ``[k, j, i]`` of an ``R^3`` grid has its centre at::

    x_i = (i + 0.5) / R - 0.5,   y_j = (j + 0.5) / R - 0.5,   z_k = (k + 0.5) / R - 0.5

inside the scene box ``[-0.5, 0.5]^3``. Families evaluate their formulas at these centres, so a
family looks the same at any resolution.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from mitsnerf.math.box import UNIT_BOX

#: Every family keeps density below 0.01 outside ``[-MARGIN, MARGIN]^3`` so the medium never touches
#: the box faces.
MARGIN = 0.45


@dataclass(frozen=True)
class VolumeGrids:
    """A family's output on an ``R^3`` grid, indexed ``[z, y, x]``.

    Attributes:
        density: float32 (R, R, R), values >= 0 (the procedural families' in [0, 1]): the shape of the
            medium, unscaled (the scene multiplies it by its ``sigma_t`` scale); with ``values =
            "sigma_t"``, the extinction itself in world units, not scaled.
        albedo: float32 (R, R, R, 3), single-scattering albedo in [0, 1].
        values: ``"density"`` (the default) or ``"sigma_t"``: what ``density`` holds.

    >>> g = VolumeGrids(np.zeros((8, 8, 8), np.float32), np.ones((8, 8, 8, 3), np.float32))
    >>> g.resolution
    8
    >>> VolumeGrids(np.zeros((8, 8, 4), np.float32), np.ones((8, 8, 4, 3), np.float32))
    Traceback (most recent call last):
    ...
    ValueError: density: must have shape (R, R, R), got (8, 8, 4)
    """

    density: np.ndarray
    albedo: np.ndarray
    values: str = "density"

    def __post_init__(self) -> None:
        d, a = self.density, self.albedo
        if self.values not in ("density", "sigma_t"):
            raise ValueError(f"values: must be 'density' or 'sigma_t', got {self.values!r}")
        if d.ndim != 3 or len(set(d.shape)) != 1:
            raise ValueError(f"density: must have shape (R, R, R), got {d.shape}")
        if a.shape != d.shape + (3,):
            raise ValueError(f"albedo: must have shape {d.shape + (3,)}, got {a.shape}")
        for name, arr in (("density", d), ("albedo", a)):
            if arr.dtype != np.float32:
                raise ValueError(f"{name}: must be float32, got {arr.dtype}")

    @property
    def resolution(self) -> int:
        """R, the number of voxels along each axis."""
        return self.density.shape[0]


@dataclass(frozen=True)
class Family:
    """A registered volume family.

    Attributes:
        name: registry key, e.g. ``"cloud"``.
        params_type: frozen dataclass of the family's parameters, built by
            :func:`mitsnerf.config.from_dict`: every field is a :func:`mitsnerf.config.param` with a
            default and its range; ``__post_init__`` checks the rules between fields (raising
            ``ValueError("field: ...")``).
        generate: ``(params, resolution, seed) -> VolumeGrids``; deterministic in its arguments (and
            in the content of the files it reads).
        description: one line saying what the family stresses.
        files: the names of ``params_type``'s fields that are paths of files ``generate`` reads (empty
            values allowed): a spec resolves relative ones against its own directory, and a dataset's
            key covers each file's sha256 rather than its path.
        check: ``(params) -> None``, optional: the checks of the files ``generate`` reads that need not read
            them whole (a header's shape, a path that is no file), raising a
            :class:`~mitsnerf.errors.SpecError` naming the file; run before anything is written.
    """

    name: str
    params_type: type
    generate: Callable[[Any, int, int], VolumeGrids]
    description: str
    files: tuple[str, ...] = ()
    check: Callable[[Any], None] | None = None


def voxel_centres(resolution: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World coordinates of the voxel centres as broadcastable float32 arrays ``(z, y, x)``.

    Shapes (R, 1, 1), (1, R, 1), (1, 1, R): any expression in them broadcasts to the (R, R, R)
    grid indexed ``[z, y, x]``.

    >>> z, y, x = voxel_centres(4)
    >>> x.ravel().tolist(), z.shape
    ([-0.375, -0.125, 0.125, 0.375], (4, 1, 1))
    """
    cx, cy, cz = (c.astype(np.float32) for c in UNIT_BOX.voxel_axes(resolution))  # math/box.py: the one rule
    return cz[:, None, None], cy[None, :, None], cx[None, None, :]


def voxels_in_ball(resolution: int, radius: float):
    """Indices and centres of the voxels whose centre lies within ``radius`` of the box centre.

    Returns ``(index, (x, y, z))``: ``index`` a tuple of three int arrays for ``grid[index]`` on an
    (R, R, R) grid, and the float32 centre coordinates of those voxels, each of shape (M,). Families
    evaluate expensive noise only there.

    >>> index, (x, y, z) = voxels_in_ball(4, 0.3)
    >>> len(x), float(abs(x).max())
    (8, 0.125)
    """
    z, y, x = voxel_centres(resolution)
    index = np.nonzero(x * x + y * y + z * z <= np.float32(radius) ** 2)
    kk, jj, ii = index
    return index, (x.ravel()[ii], y.ravel()[jj], z.ravel()[kk])


def smoothstep(edge0: float | np.ndarray, edge1: float | np.ndarray, x: np.ndarray) -> np.ndarray:
    """Cubic Hermite step: 0 for ``x <= edge0``, 1 for ``x >= edge1``, ``3t^2 - 2t^3`` between.

    >>> smoothstep(0.0, 1.0, np.array([-1.0, 0.25, 0.5, 2.0])).tolist()
    [0.0, 0.15625, 0.5, 1.0]
    """
    t = np.clip((x - edge0) / (edge1 - edge0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def constant_albedo(resolution: int, rgb: tuple[float, float, float]) -> np.ndarray:
    """A float32 (R, R, R, 3) grid filled with one RGB albedo.

    >>> constant_albedo(2, (0.1, 0.2, 0.3))[1, 0, 1].tolist() == np.float32([0.1, 0.2, 0.3]).tolist()
    True
    """
    return np.broadcast_to(np.asarray(rgb, np.float32), (resolution,) * 3 + (3,)).copy()


def finish(density: np.ndarray, albedo: np.ndarray) -> VolumeGrids:
    """Clip density to [0, 1] and albedo to [0, 1], cast both to contiguous float32 and wrap them."""
    d = np.ascontiguousarray(np.clip(density, 0.0, 1.0), dtype=np.float32)
    a = np.ascontiguousarray(np.clip(albedo, 0.0, 1.0), dtype=np.float32)
    return VolumeGrids(d, a)
