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
from typing import Any, ClassVar

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
    voxel_centres,
)
from mitsnerf.volumes.noise import NOISE_BOUND, GradientNoise, fbm

_Z_BOTTOM, _Z_TOP = -0.4, 0.4


@dataclass(frozen=True)
class Params:
    """Parameters of ``plume`` (lengths in world units); ``mitsnerf.config.doc_table(Params)`` lists them."""

    config_noun: ClassVar[str] = "parameter of volume family 'plume'"

    octaves: int = common.octaves(3, doc="fBm octaves of the filament noise")
    base_frequency: float = common.base_frequency(7.0, doc="horizontal frequency, lattice cells per unit length")
    persistence: float = common.persistence(0.5)
    lacunarity: float = common.lacunarity(2.0)
    stretch: float = param(5.0, lo=1.0, hi=16.0, doc="vertical / horizontal feature length")
    width: float = param(0.15, lo=0.0, hi=1.0, lo_open=True, doc="half-width of a ridge, in noise units")
    turbulence: float = param(0.1, lo=0.0, hi=0.3, doc="sideways displacement amplitude")
    turbulence_frequency: float = param(2.0, lo=0.0, hi=16.0, lo_open=True,
                                        doc="frequency of the displacement field")
    twist: float = param(1.5, lo=-12.0, hi=12.0, doc="rotation about z from bottom to top, radians")
    radius_bottom: float = param(0.06, lo=0.0, hi=MARGIN, lo_open=True, doc="plume radius at the bottom")
    radius_top: float = param(0.32, lo=0.0, hi=MARGIN, lo_open=True, doc="plume radius at the top")
    albedo: tuple[float, float, float] = common.albedo((0.9, 0.9, 0.9))

    def __post_init__(self) -> None:
        common.check_fbm(self)
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
    octave: dict[str, Any] = dict(frequency=params.base_frequency, octaves=params.octaves,
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
