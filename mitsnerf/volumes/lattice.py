"""``lattice``: hard-edged cubes on a regular lattice, density exactly 0 or 1.

The worst case for smooth fields and positional encodings: axis-aligned discontinuities
everywhere, and (since the cells do not align with voxels in general) point-sampling aliasing.
The sub-box ``[-half_extent, half_extent]^3`` is split into ``cells^3`` cells of side
``w = 2 half_extent / cells``; ``round(fill_fraction cells^3)`` of them (at least one), chosen at
random from the seed, hold a centred solid cube of side ``cube_fraction w``::

    c(p)    = floor((p + half_extent) / w)                  (integer cell, per axis)
    u(p)    = (p + half_extent) / w - c(p) - 1/2            (position in the cell, in [-1/2, 1/2))
    density = 1  if |p_a| < half_extent and |u_a| <= cube_fraction / 2 for a = x, y, z and filled[c]
              0  otherwise

evaluated at voxel centres, so values are exactly 0 or 1 at every resolution.

>>> g = generate(Params(), 16, seed=0)
>>> sorted(np.unique(g.density).tolist())
[0.0, 1.0]
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mitsnerf.volumes.base import MARGIN, Family, VolumeGrids, constant_albedo, finish, voxel_centres
from mitsnerf.volumes.params import check_float, check_int, check_rgb, normalise


@dataclass(frozen=True)
class Params:
    """Parameters of ``lattice`` (lengths in world units).

    | name          | type      | default         | meaning                                           |
    |---------------|-----------|-----------------|---------------------------------------------------|
    | cells         | int       | 6               | cells per axis, 1 to 64                           |
    | fill_fraction | float     | 0.4             | fraction of cells holding a cube, (0, 1]          |
    | cube_fraction | float     | 0.7             | cube side / cell side, (0, 1] (1: cubes touch)    |
    | half_extent   | float     | 0.4             | half side of the lattice's sub-box, <= 0.45       |
    | albedo        | 3 floats  | (0.8, 0.8, 0.8) | constant single-scattering albedo                 |
    """

    cells: int = 6
    fill_fraction: float = 0.4
    cube_fraction: float = 0.7
    half_extent: float = 0.4
    albedo: tuple[float, float, float] = (0.8, 0.8, 0.8)

    def __post_init__(self) -> None:
        normalise(
            self,
            cells=check_int("cells", self.cells, lo=1, hi=64),
            fill_fraction=check_float("fill_fraction", self.fill_fraction, 0.0, 1.0, lo_open=True),
            cube_fraction=check_float("cube_fraction", self.cube_fraction, 0.0, 1.0, lo_open=True),
            half_extent=check_float("half_extent", self.half_extent, 0.05, MARGIN),
            albedo=check_rgb("albedo", self.albedo),
        )


def filled_cells(params: Params, rng: np.random.Generator) -> np.ndarray:
    """Boolean (cells, cells, cells) occupancy, indexed [z, y, x], with the requested fill count."""
    n = params.cells**3
    count = max(1, round(params.fill_fraction * n))
    filled = np.zeros(n, bool)
    filled[rng.permutation(n)[:count]] = True
    return filled.reshape((params.cells,) * 3)


def generate(params: Params, resolution: int, seed: int) -> VolumeGrids:
    """Evaluate the lattice on an ``R^3`` grid; see the module docstring for the formula."""
    filled = filled_cells(params, np.random.default_rng(seed))
    h, w = params.half_extent, 2.0 * params.half_extent / params.cells
    cell, solid = [], []
    for a in voxel_centres(resolution):  # per axis: z, y, x
        s = (a.ravel().astype(np.float64) + h) / w
        c = np.floor(s)
        u = s - c - 0.5
        solid.append((np.abs(a.ravel()) < h) & (np.abs(u) <= params.cube_fraction / 2))
        cell.append(np.clip(c, 0, params.cells - 1).astype(np.intp))
    (kz, ky, kx), (sz, sy, sx) = cell, solid
    density = filled[np.ix_(kz, ky, kx)] & sz[:, None, None] & sy[None, :, None] & sx[None, None, :]
    return finish(density.astype(np.float32), constant_albedo(resolution, params.albedo))


FAMILY = Family(
    name="lattice",
    params_type=Params,
    generate=generate,
    description="hard-edged cubes on a lattice, density exactly 0 or 1 (worst case for smooth fields)",
)
