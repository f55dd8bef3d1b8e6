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
from typing import ClassVar

import numpy as np

from mitsnerf.config import param
from mitsnerf.volumes import params as common
from mitsnerf.volumes.base import MARGIN, Family, VolumeGrids, constant_albedo, finish, voxel_centres


@dataclass(frozen=True)
class Params:
    """Parameters of ``lattice`` (lengths in world units); ``mitsnerf.config.doc_table(Params)`` lists them."""

    config_noun: ClassVar[str] = "parameter of volume family 'lattice'"

    cells: int = param(6, lo=1, hi=64, doc="cells per axis")
    fill_fraction: float = param(0.4, lo=0.0, hi=1.0, lo_open=True, doc="fraction of cells holding a cube")
    cube_fraction: float = param(0.7, lo=0.0, hi=1.0, lo_open=True, doc="cube side / cell side (1: cubes touch)")
    half_extent: float = param(0.4, lo=0.05, hi=MARGIN, doc="half side of the lattice's sub-box")
    albedo: tuple[float, float, float] = common.albedo((0.8, 0.8, 0.8))


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
