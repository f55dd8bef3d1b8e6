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
from typing import ClassVar

import numpy as np

from mitsnerf.config import param
from mitsnerf.volumes import params as common
from mitsnerf.volumes.base import (
    MARGIN,
    Family,
    VolumeGrids,
    constant_albedo,
    finish,
    smoothstep,
    voxels_in_ball,
)
from mitsnerf.volumes.noise import NOISE_BOUND, GradientNoise, fbm


@dataclass(frozen=True)
class Params:
    """Parameters of ``cloud`` (lengths in world units, the box is ``[-0.5, 0.5]^3``);
    ``mitsnerf.config.doc_table(Params)`` lists them with their ranges."""

    config_noun: ClassVar[str] = "parameter of volume family 'cloud'"

    octaves: int = common.octaves(5)
    base_frequency: float = common.base_frequency(3.0)
    persistence: float = common.persistence(0.5)
    lacunarity: float = common.lacunarity(2.0)
    radius: float = param(0.32, lo=0.05, hi=MARGIN, doc="envelope radius (density 0 beyond it)")
    edge_softness: float = param(0.14, lo=0.0, hi=0.5, lo_open=True,
                                 doc="width of the envelope's fall-off inside radius")
    displacement: float = param(0.15, lo=0.0, hi=0.45, doc="how far the noise pushes the envelope in or out")
    coverage: float = param(0.45, lo=0.0, hi=1.0, doc="density where the noise is 0")
    contrast: float = param(3.5, lo=0.0, hi=20.0, doc="density change per unit of noise")
    albedo: tuple[float, float, float] = common.albedo((0.8, 0.8, 0.8))

    def __post_init__(self) -> None:
        common.check_fbm(self)
        common.check_edge_softness(self)
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
