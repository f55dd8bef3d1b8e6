"""``blobs``: a few separated Gaussian lobes with exactly empty space between them.

Stresses empty-space skipping and occupancy: most of the box is exactly zero, and the lobes are
disjoint, each a truncated Gaussian that reaches exactly 0 at three standard deviations::

    b(r)    = max(0, (exp(-r^2 / (2 sigma^2)) - exp(-9/2)) / (1 - exp(-9/2)))     (b = 0 for r >= 3 sigma)
    density = max_i b(|p - c_i|),      i = 1 .. n_blobs

The centres ``c_i`` are drawn uniformly (dart throwing) in ``[-(0.45 - 3 sigma), 0.45 - 3 sigma]^3``
so that every lobe lies inside ``[-0.45, 0.45]^3`` and any two supports are at least ``gap`` apart.

>>> g = generate(Params(n_blobs=2), 16, seed=0)
>>> bool((g.density == 0.0).mean() > 0.8), bool(g.density.max() > 0.5)
(True, True)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from mitsnerf.config import param
from mitsnerf.volumes import params as common
from mitsnerf.volumes.base import MARGIN, Family, VolumeGrids, constant_albedo, finish, voxel_centres

_CUTOFF = 3.0  # support radius in standard deviations
_TRIES = 20000


@dataclass(frozen=True)
class Params:
    """Parameters of ``blobs`` (lengths in world units); ``mitsnerf.config.doc_table(Params)`` lists them.

    The lobes must fit: the cube holding the centres must have room for ``n_blobs`` points
    ``6 sigma + gap`` apart (checked against a packing fraction of 0.2; the defaults allow 7).
    """

    config_noun: ClassVar[str] = "parameter of volume family 'blobs'"

    n_blobs: int = param(5, lo=1, hi=16, doc="number of lobes")
    sigma: float = param(0.05, lo=0.005, hi=0.1, doc="standard deviation of each lobe (support 3 sigma)")
    gap: float = param(0.05, lo=0.0, hi=0.5, doc="least empty distance between two lobes' supports")
    albedo: tuple[float, float, float] = common.albedo((0.8, 0.8, 0.8))

    def __post_init__(self) -> None:
        # Place-ability: points >= d apart in a cube of side L are disjoint balls of radius d/2 in a
        # cube of side L + d. Random sequential placement jams near a packing fraction of 0.38; asking
        # for at most 0.2 keeps dart throwing quick and reliable.
        side, spacing = 2.0 * (MARGIN - _CUTOFF * self.sigma), 2.0 * _CUTOFF * self.sigma + self.gap
        room = 0.2 * (side + spacing) ** 3 / (math.pi / 6.0 * spacing**3)
        if self.n_blobs > 1 and self.n_blobs > room:
            raise ValueError(
                f"n_blobs: {self.n_blobs} lobes of sigma {self.sigma:g} with gap {self.gap:g} do not fit "
                f"comfortably in the box (at most {math.floor(room)}); lower n_blobs, sigma or gap"
            )


def place_centres(params: Params, rng: np.random.Generator) -> np.ndarray:
    """Dart-throw ``n_blobs`` centres, (n_blobs, 3) as (x, y, z), pairwise ``>= 6 sigma + gap`` apart."""
    half = MARGIN - _CUTOFF * params.sigma
    spacing = 2.0 * _CUTOFF * params.sigma + params.gap
    darts = rng.uniform(-half, half, size=(_TRIES, 3))
    centres = [darts[0]]
    for p in darts[1:]:
        if len(centres) == params.n_blobs:
            break
        if np.min(np.linalg.norm(np.asarray(centres) - p, axis=1)) >= spacing:
            centres.append(p)
    if len(centres) < params.n_blobs:
        raise ValueError(
            f"n_blobs: placed only {len(centres)} of {params.n_blobs} lobes in {_TRIES} tries; "
            "lower n_blobs, sigma or gap"
        )
    return np.asarray(centres)


def generate(params: Params, resolution: int, seed: int) -> VolumeGrids:
    """Evaluate the lobes on an ``R^3`` grid; see the module docstring for the formula."""
    centres = place_centres(params, np.random.default_rng(seed))
    z, y, x = voxel_centres(resolution)
    floor = math.exp(-0.5 * _CUTOFF**2)
    density = np.zeros((resolution,) * 3, np.float32)
    for cx, cy, cz in centres.astype(np.float32):
        r2 = (x - cx) ** 2 + (y - cy) ** 2 + (z - cz) ** 2
        lobe = (np.exp(r2 * np.float32(-0.5 / params.sigma**2)) - floor) / np.float32(1.0 - floor)
        np.maximum(density, lobe, out=density)
    return finish(density, constant_albedo(resolution, params.albedo))


FAMILY = Family(
    name="blobs",
    params_type=Params,
    generate=generate,
    description="a few disjoint truncated Gaussian lobes in empty space (empty-space skipping)",
)
