"""The integrator's side of the verification: field callables and the image they render.

Emission-absorption renders ``C = int_0^L T(t) sigma_t(t) c(t) dt + T(L) bg`` with
``T(t) = exp(-int_0^t sigma_t)``. Physics says when that equals volpath's radiance:

- albedo 0: nothing scatters, so ``c = 0`` and ``C = T(L) bg`` (transmittance only);
- single scattering of a directional light (irradiance ``E``, travelling along ``w_L``)::

      c(x) = albedo(x) p E T_light(x),   p = 1 / (4 pi),
      T_light(x) = exp(-int_0^{s_f} sigma_t(x - s w_L) ds)       (s_f: where the ray leaves the box)

  because ``sigma_t c = sigma_s p E T_light`` is the in-scattered radiance per unit length.

A scenario's ``source`` names its builder in :data:`SOURCE_BUILDERS`: a function of the
scenario, its ``sigma_t`` and albedo grids, the loaded Mitsuba scene and the quality, returning
the field ``(x, d) -> (c, sigma_t)``. A new kind of source (say, an in-scattered radiance
``J`` estimated by Mitsuba itself) is one builder there and its name in
:data:`mitsnerf.verify.cases.SOURCES`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import drjit as dr
import numpy as np

from mitsnerf.math.box import UNIT_BOX, march_transmittance
from mitsnerf.math.camera import Camera
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


def render_image(field, camera: Camera, n_samples: int, background=None, quadrature: str = "seed",
                 jitter: Callable[[int], Any] | None = None, chunk_rays: int = 1024) -> np.ndarray:
    """Render ``camera``'s pixel-centre rays through ``field``; linear RGB ``(H, W, 3)``.

    ``jitter(size)`` gives the per-sample ``u`` of a chunk of rays (training mode), None
    the stratum midpoints (evaluation).
    """
    import mitsuba as mi

    o_np, d_np = camera_rays_numpy([camera])
    out = []
    with dr.suspend_grad():
        for start in range(0, len(o_np), chunk_rays):
            o = to_array3f(mi.Array3f, o_np[start:start + chunk_rays])
            d = to_array3f(mi.Array3f, d_np[start:start + chunk_rays])
            u = jitter(dr.width(o) * n_samples) if jitter is not None else None
            comp = render_rays(field, o, d, n_samples, box=UNIT_BOX, u=u, background=background,
                               quadrature=quadrature)
            out.append(np.stack([np.asarray(c, dtype=np.float64) for c in comp.rgb], axis=-1))
    return np.concatenate(out).reshape(camera.height, camera.width, 3)


def absorption_source(scenario, sigma_t, albedo, scene, quality):
    """``c = 0``: the true ``sigma_t``, no emission (albedo 0)."""
    from mitsnerf.fields.grid import GridField

    return GridField.from_arrays(sigma_t, UNIT_BOX, color=(0.0, 0.0, 0.0))


def single_scatter_source(scenario, sigma_t, albedo, scene, quality):
    """``c = albedo p E T_light`` of the scenario's directional light (:class:`SingleScatterSource`)."""
    from mitsnerf.fields.grid import GridField
    from mitsnerf.verify.cases import isotropic_phase

    albedo_grid = albedo if np.ndim(albedo) else np.full(sigma_t.shape[:3] + (3,), float(albedo), np.float32)
    return SingleScatterSource(GridField.from_arrays(sigma_t, UNIT_BOX),
                               GridField.from_arrays(sigma_t, UNIT_BOX, color=albedo_grid),
                               scenario.sun_direction, scenario.sun_irradiance, isotropic_phase())


def in_scattered_source(scenario, sigma_t, albedo, scene, quality):
    """``c = J = albedo (1/4pi) int L dw`` (an anisotropic medium: ``albedo int p(w . d) L dw``), estimated by
    volpath from each sample point
    (:class:`mitsnerf.oracle.compare.PointSource`: the oracle without its grid), the sun's direct term
    by shadow rays; ``quality.j_spp`` directions per point."""
    import mitsuba as mi

    from mitsnerf.fields.grid import GridField
    from mitsnerf.oracle.compare import PointSource
    from mitsnerf.oracle.source import inner_max_depth
    from mitsnerf.scene.spec import DirectionalLight
    from mitsnerf.verify import mitsuba_refs as M

    depth = inner_max_depth(scenario.max_depth)
    inner = (
        None
        if depth is None
        else (
            scene
            if depth == scenario.max_depth
            else mi.load_dict(M.scene_dict(sigma_t, albedo, M.emitters_of(scenario), depth, scenario.phase()))
        )
    )
    albedo_grid = albedo if np.ndim(albedo) else np.full(sigma_t.shape[:3] + (3,), float(albedo), np.float32)
    lights = [DirectionalLight(direction=scenario.sun_direction, irradiance=scenario.sun_irradiance)]
    return PointSource(inner, GridField.from_arrays(sigma_t, UNIT_BOX, color=albedo_grid), lights, UNIT_BOX,
                       spp=quality.j_spp, m_light=64, seed=quality.seed + 17, g=scenario.phase_g)


def scatter_field_source(scenario, sigma_t, albedo, scene, quality):
    """The ``scatter`` method's field (:class:`mitsnerf.fields.scatter.ScatterField`) holding the true medium: a
    grid medium (:class:`mitsnerf.fields.media.GridMedium`) of the scenario's ``sigma_t`` and albedo (activations
    ``relu`` and ``clamp``, so its lookups are Mitsuba's trilinear ones), the scenario's sun as its one delta
    light, its phase function, a remainder of 0; the transmittance to the sun marched from every sample
    (``shadow_resolution = 0``, 64 midpoint samples), not looked up in the training's cache: this checks the physics
    (the light's direction, the phase function, the irradiance), and the cache's own error (about 5e-3 of T at 32^3,
    tests/fields/test_scatter.py) would bias the image mean by ~1%, which the check resolves (channel-mean z -4.3
    at quick size with the cache). Its colour is then ``albedo p(w . d) E T_light``: single scattering (volpath
    ``max_depth`` 2, black environment)."""
    import mitsuba as mi

    from mitsnerf.fields.media import GridMedium, GridMediumConfig
    from mitsnerf.fields.scatter import ScatterField, ScatterFieldConfig
    from mitsnerf.scene.spec import DirectionalLight

    albedo_grid = albedo if np.ndim(albedo) else np.full(sigma_t.shape[:3] + (3,), float(albedo), np.float32)
    sun = DirectionalLight(direction=scenario.sun_direction, irradiance=scenario.sun_irradiance)
    sigma = sigma_t[..., None] if sigma_t.ndim == 3 else sigma_t
    grids = [mi.TensorXf(np.ascontiguousarray(g, dtype=np.float32)) for g in (sigma, albedo_grid)]
    medium = GridMedium(GridMediumConfig(sigma_scale=1.0, density_activation="relu", albedo_activation="clamp"),
                        grids[0], grids[1], dr.zeros(mi.TensorXf, (1, 1, 1, 3)), UNIT_BOX)
    config = ScatterFieldConfig(remainder_degree=0, zonal_degree=0, shadow_resolution=0, shadow_samples=64)
    return ScatterField(config, medium, UNIT_BOX, [sun], scenario.phase_g).with_shadows()


SOURCE_BUILDERS: dict[str, Callable[..., Any]] = {
    "zero": absorption_source,
    "single_scatter": single_scatter_source,
    "in_scattered": in_scattered_source,
    "scatter_field": scatter_field_source,
}
"""Source name (:data:`mitsnerf.verify.cases.SOURCES`) -> ``builder(scenario, sigma_t, albedo, scene, quality)``."""
