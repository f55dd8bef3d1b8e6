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

import numpy as np

from mitsnerf.volumes.base import (
    MARGIN, Family, VolumeGrids, finish, smoothstep, voxel_centres, voxels_in_ball,
)
from mitsnerf.volumes.noise import GradientNoise, fbm
from mitsnerf.volumes.params import check_fbm, check_float, check_rgb, normalise

DEFAULT_PALETTE = ((0.25, 0.45, 0.95), (0.9, 0.35, 0.7), (0.98, 0.8, 0.45))


@dataclass(frozen=True)
class Params:
    """Parameters of ``nebula`` (lengths in world units).

    | name             | type           | default          | meaning                                    |
    |------------------|----------------|------------------|--------------------------------------------|
    | octaves          | int >= 1       | 5                | fBm octaves of the density noise           |
    | base_frequency   | float          | 2.5              | lowest octave, cells per unit length       |
    | persistence      | float (0, 1]   | 0.55             | amplitude ratio between octaves            |
    | lacunarity       | float [1.5, 4] | 2.0              | frequency ratio between octaves            |
    | sheet_width      | float          | 0.12             | half-width of a sheet, in noise units      |
    | radius           | float          | 0.42             | envelope radius (density 0 beyond it)      |
    | edge_softness    | float          | 0.2              | width of the envelope's fall-off           |
    | colour_frequency | float          | 1.5              | frequency of the colour noise              |
    | colour_contrast  | float          | 4.0              | palette position change per noise unit     |
    | palette          | K >= 2 RGBs    | blue, pink, gold | albedo colours, in [0, 1]                  |

    Default palette: ``((0.25, 0.45, 0.95), (0.9, 0.35, 0.7), (0.98, 0.8, 0.45))``.
    """

    octaves: int = 5
    base_frequency: float = 2.5
    persistence: float = 0.55
    lacunarity: float = 2.0
    sheet_width: float = 0.12
    radius: float = 0.42
    edge_softness: float = 0.2
    colour_frequency: float = 1.5
    colour_contrast: float = 4.0
    palette: tuple[tuple[float, float, float], ...] = DEFAULT_PALETTE

    def __post_init__(self) -> None:
        normalise(self, **check_fbm(self.octaves, self.base_frequency, self.persistence, self.lacunarity))
        palette = self.palette
        if isinstance(palette, (str, bytes)) or not hasattr(palette, "__len__") or len(palette) < 2:
            raise ValueError(f"palette: must be a list of at least 2 RGB colours in [0, 1], got {palette!r}")
        normalise(
            self,
            sheet_width=check_float("sheet_width", self.sheet_width, 0.0, 1.0, lo_open=True),
            radius=check_float("radius", self.radius, 0.05, MARGIN),
            edge_softness=check_float("edge_softness", self.edge_softness, 0.0, 0.5, lo_open=True),
            colour_frequency=check_float("colour_frequency", self.colour_frequency, 0.0, 16.0, lo_open=True),
            colour_contrast=check_float("colour_contrast", self.colour_contrast, 0.0, 100.0),
            palette=tuple(check_rgb(f"palette[{k}]", c) for k, c in enumerate(palette)),
        )
        if self.edge_softness > self.radius:
            raise ValueError(
                f"edge_softness: must be <= radius ({self.radius:g}), got {self.edge_softness:g}"
            )


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
