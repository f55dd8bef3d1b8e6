"""The oracle of an anisotropic (Henyey-Greenstein) medium: a view-dependent emission-absorption colour.

With a phase function ``p`` the radiance volpath renders is the emission-absorption integral with
``sigma = sigma_t`` and the colour (:mod:`mitsnerf.math.phase`)::

    c(x, d) = albedo(x) [ int p(w . d) L(x, w) dw + sum_l p(w_l(x) . d) E_l T_l(x) ]

The delta lights' unscattered light (the second term) is exact, each light's ``E_l T_l`` on its own grid
(a sun is a delta on the sphere: expanded in harmonics it would need every order). The rest, ``L(x, w)``
(environment and multiple scattering, what volpath brings from direction ``w``), is estimated by volpath
from the voxel centres and projected on real spherical harmonics up to ``order`` (the same uniform directions
as the isotropic oracle's ``Lbar_mc``, which is its coefficient 0 over ``sqrt(4 pi)``); Henyey-Greenstein then
acts per band as ``g^l`` (Funk-Hecke). A truncated series rings negative: the bands are windowed (Lanczos,
:func:`mitsnerf.math.phase.band_factors`) and ``c`` is clamped at 0 (:class:`~mitsnerf.oracle.field.
DirectionalOracleField`). The ceiling is scored at every order of ``report_orders`` too, so the table of
orders says where it has converged.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mitsnerf.config import check_fields, param
from mitsnerf.math.box import Box
from mitsnerf.math.phase import WINDOWS


@dataclass(frozen=True)
class DirectionalConfig:
    """The directional oracle's settings (anisotropic media only); the grid resolution and seed are the oracle's
    own (:class:`mitsnerf.oracle.cache.OracleConfig`), and so are the volpath directions if ``spp`` is 0.

    The defaults, measured on cloud_hg85 at library size (docs/notes/oracle.md, "At library size: cloud_hg85 as
    the physics table scores it, and the settings chosen"): at 1024 directions per point the order has converged
    by 8 (8 -> 9: +0.05 dB), and the ceiling is limited by the Monte Carlo noise of the coefficients, 47% of its
    error; it halves per doubling, so 2048 puts it at about 0.3, at 16x the isotropic oracle's volpath time.
    """

    spp: int = param(2048, lo=0, doc="volpath directions per grid point (0: the oracle's spp); the high orders' "
                                     "coefficients are noisy and need more than an isotropic oracle's Lbar_mc")
    order: int = param(8, lo=0, hi=9, doc="spherical-harmonic order L of the in-scattered radiance (Dr.Jit: <= 9)")
    window: str = param("lanczos", choices=WINDOWS, doc="taper of the truncated series' bands (none: g^l only)")
    report_orders: tuple[int, ...] = param((0, 1, 2, 4, 6), lo=0, hi=9,
                                           doc="lower orders the ceiling is also scored at (its convergence)")

    def __post_init__(self) -> None:
        if isinstance(self.report_orders, list):
            object.__setattr__(self, "report_orders", tuple(self.report_orders))
        check_fields(self)

    def orders(self) -> tuple[int, ...]:
        """Every order scored, increasing, ``order`` last.

        >>> DirectionalConfig(order=4, report_orders=(0, 2, 6)).orders()
        (0, 2, 4)
        """
        return tuple(sorted({o for o in self.report_orders if o < self.order} | {self.order}))


@dataclass(frozen=True)
class DirectionalGrids:
    """What the estimate made: ``sh`` ``(R, R, R, (L + 1)^2, 3)`` coefficients ``L_lm`` and their standard error
    ``sh_se`` (zero where not needed), ``irradiance`` ``(R_d, R_d, R_d, n, 3)`` the delta lights' ``E_l T_l``."""

    sh: np.ndarray
    sh_se: np.ndarray
    sh_errors: np.ndarray
    """``(replicas, R, R, R, K, 3)`` error patterns of ``sh`` (:class:`mitsnerf.oracle.source.RadianceSH`)."""
    irradiance: np.ndarray
    lights: Sequence[Any]
    g: float
    spp: int
    points: int
    seconds: dict = field(default_factory=dict)


def estimate(scene, lights: Sequence[Any], g: float, sigma_t: np.ndarray, box: Box, resolution: int,
             delta_resolution: int, spp: int, order: int, seed: int = 0, replicas: int = 1) -> DirectionalGrids:
    """:class:`DirectionalGrids` of a scene (``scene``: the Mitsuba scene with volpath at the inner depth, None when
    nothing in-scatters; ``lights``: the spec's)."""
    from mitsnerf.oracle.source import delta_irradiance, needed_voxels, radiance_sh
    from mitsnerf.scene.lights import delta_lights
    from mitsnerf.scoring.density import true_density
    from mitsnerf.scoring.medium import mask_samples

    t0 = time.perf_counter()
    k = (order + 1) ** 2
    need = needed_voxels(sigma_t, resolution)
    sh, se = np.zeros((resolution,) * 3 + (k, 3)), np.zeros((resolution,) * 3 + (k, 3))
    errors = np.zeros((replicas,) + sh.shape)
    if scene is not None and need.any():
        found_sh = radiance_sh(scene, box.voxel_centres(resolution)[need], spp, order, seed, replicas)
        sh[need], se[need], errors[:, need] = found_sh.mean, found_sh.se, found_sh.errors
    t1 = time.perf_counter()
    found = delta_lights(lights)
    irradiance = np.zeros((delta_resolution,) * 3 + (len(found), 3))
    need_d = needed_voxels(sigma_t, delta_resolution)
    if scene is not None and need_d.any() and found:
        irradiance[need_d] = delta_irradiance(found, true_density(sigma_t, box), box.voxel_centres(delta_resolution)[
            need_d], box, mask_samples(sigma_t, box))
    seconds = {"volpath": t1 - t0, "delta_lights": time.perf_counter() - t1}
    f32 = np.float32
    return DirectionalGrids(sh.astype(f32), se.astype(f32), errors.astype(f32), irradiance.astype(f32), tuple(found),
                            float(g), spp, int(need.sum()), seconds)


def oracle_field(grids: DirectionalGrids, sigma_t: np.ndarray, albedo, box: Box, order: int, window: str):
    """The oracle field of ``grids`` truncated at ``order``."""
    from mitsnerf.oracle.field import DirectionalOracleField

    return DirectionalOracleField.from_grids(sigma_t, albedo, grids.sh, grids.g, grids.lights, grids.irradiance, box,
                                             order=order, window=window)


def image_variance(grids: DirectionalGrids, sigma_t: np.ndarray, albedo, cameras, box: Box, n_samples: int,
                   config: DirectionalConfig, *, pixel_center: float = 0.5, footprint: int = 1) -> np.ndarray:
    """The oracle image's Monte Carlo variance (V, H, W, 3): :func:`pattern_variance` of its error patterns."""
    return pattern_variance(grids.sh_errors, sigma_t, albedo, grids.g, cameras, box, n_samples, config.order,
                            config.window, pixel_center=pixel_center, footprint=footprint)


def pattern_variance(patterns: np.ndarray, sigma_t: np.ndarray, albedo, g: float, cameras, box: Box, n_samples: int,
                     order: int, window: str, *, pixel_center: float = 0.5, footprint: int = 1) -> np.ndarray:
    """The Monte Carlo variance (V, H, W, 3) of an image of the coefficients whose error ``patterns`` (replicas, R, R,
    R, K, 3) are: the mean square of the unclamped renders of the patterns, without the lights. The image is linear
    in the coefficients, and the patterns carry their covariance, as :func:`mitsnerf.oracle.field.image_variance`'s
    random signs carry the isotropic oracle's voxel variances: ``E[C_e^2] = Var(C)``."""
    from mitsnerf.oracle.field import DirectionalOracleField, render_field

    no_lights = np.zeros((1, 1, 1, 0, 3), np.float32)
    total = np.zeros((len(cameras), cameras[0].height, cameras[0].width, 3))
    for pattern in patterns:
        f = DirectionalOracleField.from_grids(sigma_t, albedo, pattern, g, (), no_lights, box, order=order,
                                              window=window, clamp=False)
        image = render_field(f, cameras, box, n_samples, pixel_center=pixel_center, footprint=footprint)
        total += np.square(image.astype(np.float64))
    return total / len(patterns)
