"""``nebula``: noise sheets whose single-scattering albedo varies in colour across space.

Stresses the colour channels: a method that learns one albedo per ray, or ties colour to density,
fails here. Density comes from ridged fBm (thin sheets around the noise's zero set) inside a soft
sphere; albedo from a second, independent low-frequency fBm mapped through a piecewise-linear
palette::

    n_d(p)   = fbm_1(p; base_frequency, octaves, persistence, lacunarity)
    env(p)   = 1 - smoothstep(radius - edge_softness, radius, |p|)
    density  = env(p) * clip(1 - |n_d(p)| / sheet_width, 0, 1)^2
    s(p)     = clip(1/2 + colour_contrast * fbm_2(p; colour_frequency, 3 octaves), 0, 1)
    albedo   = palette(s(p))    (linear between the palette's K colours placed at s = k / (K - 1))

>>> g = generate(Params(), 16, seed=0)
>>> g.albedo.shape, bool(g.albedo.reshape(-1, 3).std(axis=0).min() > 0.05)
((16, 16, 16, 3), True)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from mitsnerf.config import param
from mitsnerf.volumes import params as common
from mitsnerf.volumes.base import (
    MARGIN,
    Family,
    VolumeGrids,
    finish,
    smoothstep,
    voxel_centres,
    voxels_in_ball,
)
from mitsnerf.volumes.noise import GradientNoise, fbm

DEFAULT_PALETTE = ((0.25, 0.45, 0.95), (0.9, 0.35, 0.7), (0.98, 0.8, 0.45))


@dataclass(frozen=True)
class Params:
    """Parameters of ``nebula`` (lengths in world units); ``mitsnerf.config.doc_table(Params)`` lists them.

    Default palette: ``((0.25, 0.45, 0.95), (0.9, 0.35, 0.7), (0.98, 0.8, 0.45))`` (blue, pink, gold).
    """

    config_noun: ClassVar[str] = "parameter of volume family 'nebula'"

    octaves: int = common.octaves(5, doc="fBm octaves of the density noise")
    base_frequency: float = common.base_frequency(2.5)
    persistence: float = common.persistence(0.55)
    lacunarity: float = common.lacunarity(2.0)
    sheet_width: float = param(0.12, lo=0.0, hi=1.0, lo_open=True, doc="half-width of a sheet, in noise units")
    radius: float = param(0.42, lo=0.05, hi=MARGIN, doc="envelope radius (density 0 beyond it)")
    edge_softness: float = param(0.2, lo=0.0, hi=0.5, lo_open=True, doc="width of the envelope's fall-off")
    colour_frequency: float = param(1.5, lo=0.0, hi=16.0, lo_open=True, doc="frequency of the colour noise")
    colour_contrast: float = param(4.0, lo=0.0, hi=100.0, doc="palette position change per unit of noise")
    palette: tuple[tuple[float, float, float], ...] = param(
        DEFAULT_PALETTE, lo=0.0, hi=1.0, doc="K >= 2 albedo colours (RGB), placed at s = k / (K - 1)")

    def __post_init__(self) -> None:
        common.check_fbm(self)
        if len(self.palette) < 2:
            raise ValueError(
                f"palette: must be a list of at least 2 RGB colours in [0, 1], got {[list(c) for c in self.palette]}"
            )
        common.check_edge_softness(self)


def apply_palette(s: np.ndarray, palette) -> np.ndarray:
    """Map positions ``s`` in [0, 1] (any shape) to RGB (shape + (3,)) through the palette.

    >>> apply_palette(np.array([0.0, 0.25, 1.0]), ((0, 0, 0), (1, 0.5, 0), (1, 1, 1))).tolist()
    [[0.0, 0.0, 0.0], [0.5, 0.25, 0.0], [1.0, 1.0, 1.0]]
    """
    colours = np.asarray(palette, np.float64)
    stops = np.linspace(0.0, 1.0, len(colours))
    return np.stack([np.interp(s, stops, colours[:, c]) for c in range(3)], axis=-1)


def generate(params: Params, resolution: int, seed: int) -> VolumeGrids:
    """Evaluate the nebula on an ``R^3`` grid; see the module docstring for the formula."""
    rng = np.random.default_rng(seed)
    shape_noise, colour_noise = GradientNoise(rng), GradientNoise(rng)
    index, (x, y, z) = voxels_in_ball(resolution, params.radius)  # density is 0 outside
    n = fbm(
        shape_noise, x, y, z,
        frequency=params.base_frequency, octaves=params.octaves,
        persistence=params.persistence, lacunarity=params.lacunarity,
    )
    r = np.sqrt(x * x + y * y + z * z)
    env = 1.0 - smoothstep(params.radius - params.edge_softness, params.radius, r)
    sheet = np.clip(1.0 - np.abs(n) / np.float32(params.sheet_width), 0.0, 1.0)
    density = np.zeros((resolution,) * 3, np.float32)
    density[index] = env * sheet * sheet
    z, y, x = voxel_centres(resolution)  # albedo everywhere, so that it interpolates smoothly
    m = fbm(colour_noise, x, y, z, frequency=params.colour_frequency, octaves=3)
    s = np.clip(0.5 + params.colour_contrast * m, 0.0, 1.0)
    return finish(density, apply_palette(s, params.palette))


FAMILY = Family(
    name="nebula",
    params_type=Params,
    generate=generate,
    description="ridged-noise sheets with spatially varying RGB albedo from a palette",
)
