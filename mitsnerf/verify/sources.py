"""The integrator's side of the verification: field callables and the image they render.

Emission-absorption renders ``C = int_0^L T(t) sigma_t(t) c(t) dt + T(L) bg`` with
``T(t) = exp(-int_0^t sigma_t)``. Physics says when that equals volpath's radiance:

- albedo 0: nothing scatters, so ``c = 0`` and ``C = T(L) bg`` (transmittance only);
- albedo 1 in an environment of constant radiance 1 (white furnace): the radiance is 1
  everywhere, which ``c = 1``, ``bg = 1`` reproduce (``int T sigma_t + T(L) = 1``);
- single scattering of a directional light (irradiance ``E``, travelling along ``w_L``)::

      c(x) = albedo(x) p E T_light(x),   p = 1 / (4 pi),
      T_light(x) = exp(-int_0^{s_f} sigma_t(x - s w_L) ds)       (s_f: where the ray leaves the box)

  because ``sigma_t c = sigma_s p E T_light`` is the in-scattered radiance per unit length.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import drjit as dr
import numpy as np

from mitsnerf.math.box import UNIT_BOX, march_transmittance
from mitsnerf.math.camera import Camera
from mitsnerf.math.composite import composite
from mitsnerf.math.rays import camera_rays_numpy, to_array3f
from mitsnerf.render.volume import render_rays


@dataclass(frozen=True)
class SingleScatterSource:
    """``(x, d) -> (c, sigma_t)`` with ``c = albedo(x) p E T_light(x)`` (see the module docstring).

    ``sigma_field``, ``albedo_field``: :class:`~mitsnerf.fields.grid.GridField` s (sigma_t; albedo
    as colour). ``light_direction`` is the way the light travels; ``m_light`` samples per light march.
    """

    sigma_field: Any
    albedo_field: Any
    light_direction: tuple[float, float, float]
    irradiance: tuple[float, float, float]
    phase: float
    m_light: int = 64

    def __call__(self, x, d):
        Array3f = type(x)
        albedo, sigma = self.albedo_field(x, d)
        to_light = -Array3f(*self.light_direction)
        T_light = march_transmittance(self.sigma_field.density, x, to_light, self.m_light, self.sigma_field.box)
        scale = Array3f(*self.irradiance) * self.phase
        return albedo * scale * T_light, sigma


def render_image(field, camera: Camera, n_samples: int, background=None, composite_fn=composite,
                 chunk_rays: int = 1024) -> np.ndarray:
    """Render ``camera``'s pixel-centre rays through ``field`` (midpoints); linear RGB ``(H, W, 3)``."""
    import mitsuba as mi

    o_np, d_np = camera_rays_numpy([camera])
    out = []
    with dr.suspend_grad():
        for start in range(0, len(o_np), chunk_rays):
            o = to_array3f(mi.Array3f, o_np[start:start + chunk_rays])
            d = to_array3f(mi.Array3f, d_np[start:start + chunk_rays])
            comp = render_rays(field, o, d, n_samples, background=background, composite_fn=composite_fn, box=UNIT_BOX)
            out.append(np.stack([np.asarray(c, dtype=np.float64) for c in comp.rgb], axis=-1))
    return np.concatenate(out).reshape(camera.height, camera.width, 3)
