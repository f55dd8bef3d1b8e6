"""``shell``: a thin, dense, hollow sphere or torus with sharp edges.

Stresses thin, nearly opaque surfaces inside a volume (high optical depth over a short distance, a
hard density step, an empty interior that is only seen through the wall). Distance to the surface::

    sphere:  s(p) = |p| - radius
    torus:   s(p) = sqrt((sqrt(x^2 + z^2) - radius)^2 + y^2) - tube_radius      (axis y)
    density = clip(1/2 + (thickness/2 - |s(p)|) / h, 0, 1),      h = 1/R, the voxel size

i.e. 1 inside the wall of the given thickness and 0 outside, with a one-voxel linear ramp: the
exact wall's volume fraction in each voxel to first order (sharp at every resolution, and no
staircase along the wall). A wall thinner than a voxel peaks below 1, its volume fraction, which
keeps the optical depth through it right at coarse resolutions. The seed is unused: the shape is
fully determined by the parameters.

>>> a, b = generate(Params(), 64, seed=0), generate(Params(), 64, seed=1)
>>> bool((a.density == b.density).all()), float(a.density.max()), float(a.density[32, 32, 32])
(True, 1.0, 0.0)
>>> round(float(a.density.mean()), 4)  # the wall's volume 4 pi radius^2 thickness = 0.0339
0.0339
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from mitsnerf.config import param
from mitsnerf.volumes import params as common
from mitsnerf.volumes.base import MARGIN, Family, VolumeGrids, constant_albedo, finish, voxel_centres

SHAPES = ("sphere", "torus")


@dataclass(frozen=True)
class Params:
    """Parameters of ``shell`` (lengths in world units); ``mitsnerf.config.doc_table(Params)`` lists them."""

    config_noun: ClassVar[str] = "parameter of volume family 'shell'"

    shape: str = param("sphere", choices=SHAPES, doc="a hollow sphere or a torus (axis y)")
    radius: float = param(0.3, lo=0.0, hi=MARGIN, lo_open=True, doc="sphere radius, or the torus's major radius")
    tube_radius: float = param(0.12, lo=0.0, hi=MARGIN, lo_open=True,
                               doc="the torus's minor radius (unused by a sphere)")
    thickness: float = param(0.03, lo=0.0, hi=0.2, lo_open=True, doc="wall thickness")
    albedo: tuple[float, float, float] = common.albedo((0.7, 0.7, 0.7))

    def __post_init__(self) -> None:
        outer = self.radius + self.thickness / 2
        if self.shape == "torus":
            if self.tube_radius + self.thickness / 2 >= self.radius:
                raise ValueError(
                    f"tube_radius: tube_radius + thickness/2 must be < radius ({self.radius:g}) "
                    f"for a torus, got {self.tube_radius:g} + {self.thickness / 2:g}"
                )
            outer += self.tube_radius
        if outer > MARGIN:
            raise ValueError(f"radius: the shell reaches {outer:g} from the centre, more than {MARGIN:g}")
        if self.thickness / 2 >= (self.tube_radius if self.shape == "torus" else self.radius):
            raise ValueError("thickness: the wall must be thinner than the shape is wide (not hollow)")


def surface_distance(params: Params, x, y, z) -> np.ndarray:
    """Signed distance ``s(p)`` to the sphere or torus surface (negative inside), broadcast shape."""
    if params.shape == "sphere":
        return np.sqrt(x * x + y * y + z * z) - np.float32(params.radius)
    ring = np.sqrt(x * x + z * z) - np.float32(params.radius)
    return np.sqrt(ring * ring + y * y) - np.float32(params.tube_radius)


def generate(params: Params, resolution: int, seed: int) -> VolumeGrids:
    """Evaluate the shell on an ``R^3`` grid; ``seed`` is unused (see the module docstring)."""
    del seed
    z, y, x = voxel_centres(resolution)
    s = surface_distance(params, x, y, z)
    density = 0.5 + (np.float32(params.thickness / 2) - np.abs(s)) * np.float32(resolution)
    return finish(density, constant_albedo(resolution, params.albedo))


FAMILY = Family(
    name="shell",
    params_type=Params,
    generate=generate,
    description="thin dense hollow sphere or torus with sharp edges (seed unused)",
)
