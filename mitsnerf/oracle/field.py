"""The oracle as a field ``(x, d) -> (J(x), sigma_t(x))``, rendered by the package's own integrator.

``J(x) = albedo(x) (Lbar_mc(x) + Lbar_delta(x))`` (:mod:`mitsnerf.oracle.source`), every factor a
trilinear grid lookup over the scene box (Mitsuba's ``gridvolume`` rule), ``sigma_t`` the true grid.
Rendering it at the N stratum midpoints of :func:`mitsnerf.render.volume.render_rays` (through
:func:`mitsnerf.render.march.march_rays`, the same quadrature as one loop per ray; the dataset's
background behind) gives the best image any emission-absorption model can make of the dataset at
that grid resolution, up to the Monte Carlo error of ``Lbar_mc``:

    C_p = sum_i T_i (1 - exp(-sigma_i delta_i)) J_i + T_N bg = sum_v a_pv Lbar_v + (terms without Lbar_mc)

is linear in the grid values ``Lbar_v``, so independent voxel errors of standard error ``se_v``
give the pixel variance ``Var(C_p) = sum_v a_pv^2 se_v^2``. :func:`image_variance` estimates it
without forming ``a_pv``: rendering ``Lbar_v = eps_v se_v`` (random signs ``eps_v = +-1``, no
background, no delta term) gives ``C_eps = sum_v a_pv eps_v se_v`` with ``E[C_eps^2] = Var(C_p)``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from mitsnerf.fields.grid import GridField
from mitsnerf.math.box import Box
from mitsnerf.render.camera import render_view
from mitsnerf.render.march import march_rays


@dataclass(frozen=True)
class OracleField:
    """``(x, d) -> (albedo(x) (mc(x) + delta(x)), sigma_t(x))``; build with :meth:`from_grids`.

    >>> import mitsuba as mi
    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> from mitsnerf.math.box import UNIT_BOX
    >>> ones = np.ones((2, 2, 2, 3), np.float32)
    >>> f = OracleField.from_grids(np.full((2, 2, 2), 3.0), 0.5 * ones, 0.2 * ones, 0.1 * ones, UNIT_BOX)
    >>> f(mi.Array3f(0.1, 0.2, 0.3), mi.Array3f(0, 0, 1))    # 0.5 * (0.2 + 0.1)
    ([[0.15, 0.15, 0.15]], [3])
    """

    medium: GridField
    """``sigma_t`` with the albedo as its colour."""
    mc: GridField
    delta: GridField | None

    @classmethod
    def from_grids(cls, sigma_t: np.ndarray, albedo, mc: np.ndarray, delta: np.ndarray | None, box: Box) -> OracleField:
        """Grids ``[z, y, x(, 3)]``: ``albedo`` (R, R, R, 3) or an RGB tuple; ``delta`` None for none."""
        def colour(grid):
            return GridField.from_arrays(np.zeros(grid.shape[:3], np.float32), box, color=grid)

        return cls(GridField.from_arrays(sigma_t, box, color=albedo), colour(mc),
                   None if delta is None else colour(delta))

    def __call__(self, x, d):
        albedo, sigma = self.medium(x, d)
        lbar, _ = self.mc(x, d)
        if self.delta is not None:
            lbar = lbar + self.delta(x, d)[0]
        return albedo * lbar, sigma


def render_field(field, cameras: Sequence[Any], box: Box, n_samples: int, *, background=None,
                 pixel_center: float = 0.5, footprint: int = 1) -> np.ndarray:
    """Linear RGB ``(V, H, W, 3)`` float32 of ``field`` seen by ``cameras`` (midpoints, ``footprint^2`` rays a pixel).

    The march (:func:`mitsnerf.render.march.march_rays`) equals ``render_rays`` at the midpoints and
    stores nothing per sample: 3.5x faster at the oracle's N = 128 (benchmarks/README.md, "Throughput")."""
    def renderer(o, d):
        return march_rays(field, o, d, n_samples, box=box, background=background)

    return np.stack([render_view(renderer, cam, pixel_center=pixel_center, footprint=footprint).rgb
                     for cam in cameras])


def image_variance(sigma_t: np.ndarray, albedo, mc_se: np.ndarray, cameras: Sequence[Any], box: Box,
                   n_samples: int, *, pixel_center: float = 0.5, footprint: int = 1, replicas: int = 4,
                   seed: int = 0) -> np.ndarray:
    """``Var(C_p)`` (V, H, W, 3) of the oracle image from the voxels' standard errors ``mc_se`` (module docstring).

    The mean of ``C_eps^2`` over ``replicas`` independent sign patterns: unbiased; per pixel its
    relative error is about ``sqrt(2 / replicas)``, and a mean over many pixels is far better.

    >>> import mitsuba as mi
    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> from mitsnerf.math.box import UNIT_BOX
    >>> from mitsnerf.math.camera import Camera, look_at
    >>> cam = Camera.from_fov(look_at((0, -2, 0)), 1, 1, 1.0)      # one ray through the box centre
    >>> se = np.full((1, 1, 1, 3), 0.1, np.float32)                 # one voxel: C = (1 - e^-2) Lbar
    >>> var = image_variance(np.full((1, 1, 1), 2.0), (1.0, 1.0, 1.0), se, [cam], UNIT_BOX, 64, replicas=2)
    >>> bool(np.allclose(var, (0.1 * (1 - np.exp(-2 * 127 / 128))) ** 2, rtol=1e-4))
    True
    """
    rng = np.random.default_rng(seed)
    total = np.zeros((len(cameras), cameras[0].height, cameras[0].width, 3))
    for _ in range(replicas):
        signs = rng.choice(np.array([-1.0, 1.0], np.float32), size=mc_se.shape)
        field = OracleField.from_grids(sigma_t, albedo, signs * mc_se, None, box)
        image = render_field(field, cameras, box, n_samples, pixel_center=pixel_center, footprint=footprint)
        total += np.square(image.astype(np.float64))
    return total / replicas
