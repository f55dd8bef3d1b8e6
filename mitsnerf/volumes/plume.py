"""``plume``: thin rising wisps, a high-frequency, anisotropic field.

Stresses what smooth fields and coarse grids miss: thin filaments (a few voxels across at 128^3)
stretched along the rising axis ``z`` (the world's up: mitsnerf is Z-up), twisted and
displaced sideways by low-frequency turbulence.

With ``t = (z + 0.4) / 0.8`` the height in the plume (0 at the bottom, 1 at the top)::

    (x', y')  = rotate_z(twist * t) (x, y) + turbulence * (m_1(p), m_2(p))     m_i: 2-octave fBm at
                                                                              turbulence_frequency
    q         = (f x', f y', f z / stretch)                                    f = base_frequency
    ridge_i   = clip(1 - |fbm_i(q)| / width, 0, 1)^2                           i = 1, 2
    env       = (1 - smoothstep(0.5 R(t), R(t), rho)) * smoothstep(0, 0.15, t) * (1 - smoothstep(0.8, 1, t))
    R(t)      = radius_bottom + (radius_top - radius_bottom) t,    rho = sqrt(x'^2 + y'^2)
    density   = env * ridge_1 * ridge_2

Each ridge is a thin sheet around a zero set of noise, vertical because the noise is stretched along
``z``; the product of two is non-zero near their intersections: vertical filaments.
``radius_top + turbulence * sqrt(3)/2 <= 0.45`` keeps the medium off the box faces.

>>> g = generate(Params(), 16, seed=0)
>>> g.density.shape, bool(0.0 < g.density.mean() < 0.2), bool(g.density[0].max() == 0.0)
((16, 16, 16), True, True)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mitsnerf.volumes.base import (
    MARGIN, Family, VolumeGrids, constant_albedo, finish, smoothstep, voxel_centres,
)
from mitsnerf.volumes.noise import NOISE_BOUND, GradientNoise, fbm
from mitsnerf.volumes.params import check_fbm, check_float, check_rgb, normalise

_Z_BOTTOM, _Z_TOP = -0.4, 0.4


@dataclass(frozen=True)
class Params:
    """Parameters of ``plume`` (lengths in world units).

    | name                  | type           | default         | meaning                                     |
    |-----------------------|----------------|-----------------|---------------------------------------------|
    | octaves               | int >= 1       | 3               | fBm octaves of the filament noise           |
    | base_frequency        | float          | 7.0             | horizontal frequency, cells per unit length |
    | persistence           | float (0, 1]   | 0.5             | amplitude ratio between octaves             |
    | lacunarity            | float [1.5, 4] | 2.0             | frequency ratio between octaves             |
    | stretch               | float [1, 16]  | 5.0             | vertical / horizontal feature length        |
    | width                 | float          | 0.15            | half-width of a ridge, in noise units       |
    | turbulence            | float          | 0.1             | sideways displacement amplitude             |
    | turbulence_frequency  | float          | 2.0             | frequency of the displacement field         |
    | twist                 | float          | 1.5             | rotation about z from bottom to top, radians|
    | radius_bottom         | float          | 0.06            | plume radius at the bottom                  |
    | radius_top            | float          | 0.32            | plume radius at the top                     |
    | albedo                | 3 floats       | (0.9, 0.9, 0.9) | constant single-scattering albedo           |
    """

    octaves: int = 3
    base_frequency: float = 7.0
    persistence: float = 0.5
    lacunarity: float = 2.0
    stretch: float = 5.0
    width: float = 0.15
    turbulence: float = 0.1
    turbulence_frequency: float = 2.0
    twist: float = 1.5
    radius_bottom: float = 0.06
    radius_top: float = 0.32
    albedo: tuple[float, float, float] = (0.9, 0.9, 0.9)

    def __post_init__(self) -> None:
        normalise(self, **check_fbm(self.octaves, self.base_frequency, self.persistence, self.lacunarity))
        normalise(
            self,
            stretch=check_float("stretch", self.stretch, 1.0, 16.0),
            width=check_float("width", self.width, 0.0, 1.0, lo_open=True),
            turbulence=check_float("turbulence", self.turbulence, 0.0, 0.3),
            turbulence_frequency=check_float(
                "turbulence_frequency", self.turbulence_frequency, 0.0, 16.0, lo_open=True
            ),
            twist=check_float("twist", self.twist, -12.0, 12.0),
            radius_bottom=check_float("radius_bottom", self.radius_bottom, 0.0, MARGIN, lo_open=True),
            radius_top=check_float("radius_top", self.radius_top, 0.0, MARGIN, lo_open=True),
            albedo=check_rgb("albedo", self.albedo),
        )
        widest = max(self.radius_bottom, self.radius_top)
        if widest + self.turbulence * NOISE_BOUND > MARGIN:
            raise ValueError(
                f"turbulence: max(radius_bottom, radius_top) + turbulence * {NOISE_BOUND:.3f} must be "
                f"<= {MARGIN:g}, got {widest:g} + {self.turbulence:g} * {NOISE_BOUND:.3f}"
            )


def generate(params: Params, resolution: int, seed: int) -> VolumeGrids:
    """Evaluate the plume on an ``R^3`` grid; see the module docstring for the formula.

    Noise is evaluated only where it can matter: the swirl inside the cylinder that can reach the
    plume, the filaments where the envelope is non-zero.
    """
    rng = np.random.default_rng(seed)
    swirl_x, swirl_y, fil_1, fil_2 = (GradientNoise(rng) for _ in range(4))
    zc, yc, xc = voxel_centres(resolution)
    reach = max(params.radius_bottom, params.radius_top) + params.turbulence * NOISE_BOUND
    candidate = (xc * xc + yc * yc <= reach * reach) & (zc >= _Z_BOTTOM) & (zc <= _Z_TOP)
    kk, jj, ii = np.nonzero(candidate)
    x, y, z = xc.ravel()[ii], yc.ravel()[jj], zc.ravel()[kk]

    t = (z - _Z_BOTTOM) / (_Z_TOP - _Z_BOTTOM)
    angle = params.twist * t
    c, s = np.cos(angle), np.sin(angle)
    ft = params.turbulence_frequency
    xw = c * x - s * y + params.turbulence * fbm(swirl_x, x, y, z, frequency=ft, octaves=2)
    yw = s * x + c * y + params.turbulence * fbm(swirl_y, x, y, z, frequency=ft, octaves=2)
    radius = params.radius_bottom + (params.radius_top - params.radius_bottom) * t
    rho = np.sqrt(xw * xw + yw * yw)
    env = 1.0 - smoothstep(0.5 * radius, radius, rho)
    env *= smoothstep(0.0, 0.15, t) * (1.0 - smoothstep(0.8, 1.0, t))

    inside = env > 0.0
    xw, yw, zs, values = xw[inside], yw[inside], z[inside] / np.float32(params.stretch), env[inside]
    octave = dict(frequency=params.base_frequency, octaves=params.octaves,
                  persistence=params.persistence, lacunarity=params.lacunarity)
    for noise in (fil_1, fil_2):
        ridge = np.clip(1.0 - np.abs(fbm(noise, xw, yw, zs, **octave)) / np.float32(params.width), 0.0, 1.0)
        values = values * ridge * ridge

    density = np.zeros((resolution,) * 3, np.float32)
    density[kk[inside], jj[inside], ii[inside]] = values
    return finish(density, constant_albedo(resolution, params.albedo))


FAMILY = Family(
    name="plume",
    params_type=Params,
    generate=generate,
    description="thin rising twisted filaments: high-frequency, anisotropic",
)
