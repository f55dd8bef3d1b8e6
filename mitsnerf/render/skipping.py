"""Rendering with empty-space skipping: the shared renderer's samples and compositing, fewer field calls.

:func:`render_rays_skipping` is :func:`mitsnerf.render.volume.render_rays` with an
occupancy grid (:mod:`mitsnerf.fields.occupancy`) deciding which samples reach the
field; the others count as empty (``sigma = 0``). The ``ngp`` and ``voxel`` methods
render through it.
"""

from __future__ import annotations

from typing import Any

import drjit as dr

from mitsnerf.fields.occupancy import OccupancyGrid, eval_masked
from mitsnerf.math.box import Box
from mitsnerf.math.composite import Composite, composite
from mitsnerf.render.volume import background_radiance, sample_rays


def render_rays_skipping(
    field,
    grid: OccupancyGrid | None,
    o,
    d,
    n_samples: int,
    *,
    box: Box,
    u=None,
    background=None,
) -> tuple[Composite, Any]:
    """:func:`mitsnerf.render.volume.render_rays` with empty-space skipping and early ray stopping.

    Samples are placed and composited exactly as there; ``field`` is evaluated only on
    the samples ``grid.sample_mask`` keeps (all of them when ``grid`` is None), the
    others count as empty (``sigma = 0``). Returns (composite, mask Bool (R*N,)).

    Example: a slab of ``sigma = 2`` seen through a grid that has not been updated
    (everything occupied) renders as without the grid::

        >>> import mitsuba as mi
        >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
        >>> from mitsnerf.fields.occupancy import OccupancyConfig
        >>> from mitsnerf.math.box import UNIT_BOX
        >>> slab = lambda x, d: (mi.Array3f(1.0) + 0 * x.x, mi.Float(2.0) + 0 * x.x)
        >>> grid = OccupancyGrid(OccupancyConfig(resolution=4), mi.Float, UNIT_BOX)
        >>> out, mask = render_rays_skipping(slab, grid, mi.Array3f(0, 0, -2), mi.Array3f(0, 0, 1), 8, box=UNIT_BOX)
        >>> out.opacity  # 1 - exp(-2 * 15/16), as render_rays
        [0.846645]
    """
    s, _ = sample_rays(o, d, n_samples, box, u)
    if grid is None:
        mask = dr.full(dr.mask_t(s.t), True, dr.width(s.t))
    else:
        mask = grid.sample_mask(s.x, s.delta, n_samples)
    rgb, sigma = eval_masked(field, s.x, s.d, mask)
    return composite(sigma, s.delta, rgb, n_samples, background=background_radiance(background, d), t=s.t), mask
