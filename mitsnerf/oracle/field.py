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

import drjit as dr
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

    @property
    def sigma_channels(self) -> int:
        """3 when ``sigma_t`` is chromatic (the march then composites each colour with its own extinction)."""
        return self.medium.sigma_channels

    def __call__(self, x, d):
        albedo, sigma = self.medium(x, d)
        lbar, _ = self.mc(x, d)
        if self.delta is not None:
            lbar = lbar + self.delta(x, d)[0]
        return albedo * lbar, sigma


def _sh_texture(coefficients: np.ndarray):
    """A trilinear texture of ``(R, R, R, K, 3)`` coefficients, channel ``3 k + c`` (Mitsuba's gridvolume rule)."""
    import mitsuba as mi

    r = coefficients.shape[0]
    data = np.ascontiguousarray(coefficients.reshape(r, r, r, -1), dtype=np.float32)
    return mi.Texture3f(mi.TensorXf(data), use_accel=False, filter_mode=dr.FilterMode.Linear,
                        wrap_mode=dr.WrapMode.Clamp)


@dataclass(frozen=True)
class DirectionalOracleField:
    """The oracle of a Henyey-Greenstein medium: ``(x, d) -> (c(x, d), sigma_t(x))`` with
    (:mod:`mitsnerf.math.phase`)::

        c(x, d) = albedo(x) [ max(0, sum_lm g^l h_l L_lm(x) Y_lm(d)) + sum_l p(w_l(x) . d) E_l T_l(x) ]

    ``L_lm``: the spherical-harmonic coefficients of the radiance volpath brings to ``x`` (environment and
    multiple scattering, :func:`mitsnerf.oracle.source.radiance_sh`), up to ``order``, with the window ``h_l``
    (:func:`mitsnerf.math.phase.band_factors`) and clamped at 0 (a truncated series rings negative); the delta
    lights' unscattered light is never expanded (a sun is a delta on the sphere): each light's ``E_l T_l``
    grid is weighted by the phase function towards the light, ``w_l = -direction`` or towards its position.
    Build with :meth:`from_grids`.

    >>> import mitsuba as mi
    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> from mitsnerf.math.box import UNIT_BOX
    >>> from mitsnerf.scene.spec import DirectionalLight
    >>> sun = DirectionalLight(direction=(0.0, 0.0, -1.0), irradiance=(1.0, 1.0, 1.0))   # from +z
    >>> sh, e = np.zeros((2, 2, 2, 1, 3), np.float32), np.ones((2, 2, 2, 1, 3), np.float32)
    >>> f = DirectionalOracleField.from_grids(np.full((2, 2, 2), 3.0), (1.0, 1.0, 1.0), sh, 0.5, [sun], e, UNIT_BOX)
    >>> x = mi.Array3f(0.1, 0.2, 0.3)
    >>> [round(f(x, mi.Array3f(0, 0, s))[0].x[0] * 4 * np.pi, 4) for s in (1, -1)]   # towards the sun: (1+g)/(1-g)^2
    [6.0, 0.2222]
    """

    medium: GridField
    """``sigma_t`` with the albedo as its colour."""
    sh: Any
    """Texture3f of the windowed ``g^l h_l L_lm``, 3 channels per coefficient."""
    order: int
    g: float
    lights: tuple
    """``(w or None, position or None, GridField of E T)`` per delta light."""
    box: Box
    clamp: bool = True
    """Clamp the series at 0 (False: the raw series, for error propagation)."""

    @classmethod
    def from_grids(cls, sigma_t: np.ndarray, albedo, sh: np.ndarray, g: float, lights, irradiance: np.ndarray,
                   box: Box, *, order: int | None = None, window: str = "lanczos",
                   clamp: bool = True) -> DirectionalOracleField:
        """``sh``: ``(R, R, R, K, 3)`` coefficients ``L_lm`` (:func:`~mitsnerf.oracle.source.radiance_sh`), used
        up to ``order`` (None: all); ``lights``: the spec's delta lights (:func:`~mitsnerf.oracle.source.
        delta_lights`) with ``irradiance`` ``(R_d, R_d, R_d, n, 3)`` their ``E_l T_l``."""
        from mitsnerf.math.phase import band_factors
        from mitsnerf.scene.spec import DirectionalLight

        full = int(round(np.sqrt(sh.shape[3]))) - 1
        order = full if order is None else order
        k = (order + 1) ** 2
        scaled = sh[:, :, :, :k] * band_factors(g, order, window)[None, None, None, :, None]
        terms: list[tuple[tuple[float, ...] | None, tuple[float, ...] | None, GridField]] = []
        for j, light in enumerate(lights):
            grid = GridField.from_arrays(np.zeros(irradiance.shape[:3], np.float32), box, color=irradiance[:, :, :, j])
            if isinstance(light, DirectionalLight):
                w = -np.asarray(light.direction, np.float64) / np.linalg.norm(light.direction)
                terms.append((tuple(float(v) for v in w), None, grid))
            else:
                terms.append((None, tuple(float(v) for v in light.position), grid))
        return cls(GridField.from_arrays(sigma_t, box, color=albedo), _sh_texture(scaled), order, float(g),
                   tuple(terms), box, clamp)

    @property
    def sigma_channels(self) -> int:
        """3 when ``sigma_t`` is chromatic (the march then composites each colour with its own extinction)."""
        return self.medium.sigma_channels

    def __call__(self, x, d):
        from mitsnerf.math.phase import hg, scattering_cosine

        Array3f = type(x)
        albedo, sigma = self.medium(x, d)
        coef = self.sh.eval(self.box.to_unit(x))
        basis = dr.sh_eval(d, self.order)
        rgb = Array3f(*(sum(y * coef[3 * k + c] for k, y in enumerate(basis)) for c in range(3)))
        if self.clamp:
            rgb = dr.maximum(rgb, 0.0)
        for w, position, grid in self.lights:
            to_light = Array3f(*w) if w is not None else dr.normalize(Array3f(*position) - x)
            rgb += hg(scattering_cosine(to_light, d), self.g) * grid(x, d)[0]
        return albedo * rgb, sigma


def render_field(field, cameras: Sequence[Any], box: Box, n_samples: int, *, background=None,
                 pixel_center: float = 0.5, footprint: int = 1) -> np.ndarray:
    """Linear RGB ``(V, H, W, 3)`` float32 of ``field`` seen by ``cameras`` (midpoints, ``footprint^2`` rays a pixel).

    The march (:func:`mitsnerf.render.march.march_rays`) equals ``render_rays`` at the midpoints and
    stores nothing per sample: 3.5x faster at the oracle's N = 128 (docs/notes/throughput.md, "Throughput")."""
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
