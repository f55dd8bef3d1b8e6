"""``cloud``: a smooth, low-frequency fBm cloud inside a soft, noise-displaced sphere.

The project's default scene. Stresses the easy case every method should get right: a smooth field
with real density contrast (clumps and holes) and a soft silhouette.

Density at a voxel centre ``p`` (``|p|`` its distance from the box centre)::

    n(p)    = fbm(p; base_frequency, octaves, persistence, lacunarity)          in about [-0.5, 0.5]
    env(p)  = 1 - smoothstep(radius - edge_softness, radius, |p| - displacement * n(p))
    density = env(p) * clip(coverage + contrast * n(p), 0, 1)

The displaced envelope makes the silhouette lumpy; the same noise inside makes denser clumps where
the surface bulges out. ``radius + displacement * sqrt(3)/2 <= 0.45`` (``|n| <= sqrt(3)/2``) keeps
the medium off the box faces.
Albedo is constant.

>>> g = generate(Params(), 16, seed=0)
>>> g.density.shape, g.albedo.shape, g.density.dtype
((16, 16, 16), (16, 16, 16, 3), dtype('float32'))
>>> bool(g.density[0].max() == 0.0), bool(g.density.max() > 0.9)
(True, True)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mitsnerf.volumes.base import (
    MARGIN, Family, VolumeGrids, constant_albedo, finish, smoothstep, voxels_in_ball,
)
from mitsnerf.volumes.noise import NOISE_BOUND, GradientNoise, fbm
from mitsnerf.volumes.params import check_fbm, check_float, check_rgb, normalise


@dataclass(frozen=True)
class Params:
    """Parameters of ``cloud`` (lengths in world units, the box is ``[-0.5, 0.5]^3``).

    | name           | type          | default         | meaning                                        |
    |----------------|---------------|-----------------|------------------------------------------------|
    | octaves        | int >= 1      | 5               | fBm octaves                                    |
    | base_frequency | float         | 3.0             | lowest octave, lattice cells per unit length   |
    | persistence    | float (0, 1]  | 0.5             | amplitude ratio between octaves                |
    | lacunarity     | float [1.5, 4]| 2.0             | frequency ratio between octaves                |
    | radius         | float         | 0.32            | envelope radius (density 0 beyond it)          |
    | edge_softness  | float         | 0.14            | width of the envelope's fall-off inside radius |
    | displacement   | float         | 0.15            | how far the noise pushes the envelope in/out   |
    | coverage       | float [0, 1]  | 0.45            | density where the noise is 0                   |
    | contrast       | float         | 3.5             | density change per unit of noise               |
    | albedo         | 3 floats      | (0.8, 0.8, 0.8) | constant single-scattering albedo              |
    """

    octaves: int = 5
    base_frequency: float = 3.0
    persistence: float = 0.5
    lacunarity: float = 2.0
    radius: float = 0.32
    edge_softness: float = 0.14
    displacement: float = 0.15
    coverage: float = 0.45
    contrast: float = 3.5
    albedo: tuple[float, float, float] = (0.8, 0.8, 0.8)

    def __post_init__(self) -> None:
        normalise(self, **check_fbm(self.octaves, self.base_frequency, self.persistence, self.lacunarity))
        normalise(
            self,
            radius=check_float("radius", self.radius, 0.05, MARGIN),
            edge_softness=check_float("edge_softness", self.edge_softness, 0.0, 0.5, lo_open=True),
            displacement=check_float("displacement", self.displacement, 0.0, 0.45),
            coverage=check_float("coverage", self.coverage, 0.0, 1.0),
            contrast=check_float("contrast", self.contrast, 0.0, 20.0),
            albedo=check_rgb("albedo", self.albedo),
        )
        if self.edge_softness > self.radius:
            raise ValueError(
                f"edge_softness: must be <= radius ({self.radius:g}), got {self.edge_softness:g}"
            )
        if self.radius + self.displacement * NOISE_BOUND > MARGIN:
            raise ValueError(
                f"displacement: radius + displacement * {NOISE_BOUND:.3f} must be <= {MARGIN:g}, got "
                f"{self.radius:g} + {self.displacement:g} * {NOISE_BOUND:.3f}"
            )


def generate(params: Params, resolution: int, seed: int) -> VolumeGrids:
    """Evaluate the cloud on an ``R^3`` grid; see the module docstring for the formula."""
    noise = GradientNoise(np.random.default_rng(seed))
    # |n| <= NOISE_BOUND, so the displaced envelope is 0 beyond radius + displacement * NOISE_BOUND
    index, (x, y, z) = voxels_in_ball(resolution, params.radius + params.displacement * NOISE_BOUND)
    n = fbm(
        noise, x, y, z,
        frequency=params.base_frequency, octaves=params.octaves,
        persistence=params.persistence, lacunarity=params.lacunarity,
    )
    r = np.sqrt(x * x + y * y + z * z) - np.float32(params.displacement) * n
    env = 1.0 - smoothstep(params.radius - params.edge_softness, params.radius, r)
    density = np.zeros((resolution,) * 3, np.float32)
    density[index] = env * np.clip(params.coverage + params.contrast * n, 0.0, 1.0)
    return finish(density, constant_albedo(resolution, params.albedo))


FAMILY = Family(
    name="cloud",
    params_type=Params,
    generate=generate,
    description="smooth low-frequency fBm cloud in a soft lumpy sphere (the default scene)",
)
