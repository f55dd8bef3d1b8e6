"""``scatter``: emission-absorption whose colour is the single scattering of the scene's known lights through the
learned medium, plus a learned remainder.

What it knows that the emission-absorption methods do not: the dataset's spec gives it the delta lights (suns,
point lights: their directions, positions and power) and the phase function, as it gives ``mitsuba-inverse``
everything. The colour of a sample is then ``albedo(x) [sum_l p(w_l . d) E_l T_l(x) + Rem(x, d)]``
(:mod:`mitsnerf.fields.scatter`): the transmittance ``T_l`` to each light is marched through the density being
learned, so the density answers for the shadows it casts as well as for what the view rays cross, and the
remainder (the environment and all light scattered more than once) is a smooth grid acting through the phase
function's bands. With the true medium and the remainder at its best this is the oracle's colour at the
remainder's orders, the ceiling of this rung (benchmarks/README.md).

Training: the density and albedo grids coarse to fine as ``voxel`` (doubled after each of ``upsample_steps``),
the remainder on its own coarser grid; total-variation priors on all three; the shadow cache recomputed from the
density at every training step, inside the step's AD graph, and once per parameter change for evaluation;
samples skipped in empty cells by an occupancy grid as ``voxel`` and ``ngp``. Foreign datasets (no manifest
spec: the lights are unknown) are refused in one line.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from types import MappingProxyType
from typing import Any

import drjit as dr
import mitsuba as mi

from mitsnerf.config import check_fields, param
from mitsnerf.fields.occupancy import OccupancyConfig
from mitsnerf.fields.scatter import ScatterField, ScatterFieldConfig
from mitsnerf.fields.voxel import total_variation, upsample
from mitsnerf.math.rays import fibonacci_directions, to_array3f
from mitsnerf.methods.base import MethodConfig, ParameterShapeError, RenderOutput, SceneInfo, scene_spec
from mitsnerf.methods.occupancy import OccupancyModel

SIGMA_KEY, ALBEDO_KEY, REST_KEY = "sigma_raw", "albedo_raw", "rest"
KEYS = (SIGMA_KEY, ALBEDO_KEY, REST_KEY)


@dataclass(frozen=True)
class ScatterMethodConfig(MethodConfig):
    """Configuration of the ``scatter`` method."""

    field: ScatterFieldConfig = param(default_factory=ScatterFieldConfig)
    """The grids' activations and starts, the remainder's orders and the shadow cache."""
    density_channels: int = param(0, choices=(0, 1, 3))
    """0: one density per colour where the dataset's extinction is chromatic (its spec's ``sigma_t_scale`` an RGB
    triple), else one; 1 or 3: as given."""
    resolution: int = param(64, lo=2, hi=512)
    """Final resolution of the density and albedo grids (voxels per axis)."""
    initial_resolution: int = param(32, lo=2, hi=512)
    """Their resolution at the start; doubled after each of ``upsample_steps`` until ``resolution``."""
    upsample_steps: tuple[int, ...] = param((150,), lo=0)
    """Steps (0-based, increasing) after which the density and albedo grids are doubled."""
    rest_resolution: int = param(16, lo=1, hi=256)
    """The remainder grid's resolution (fixed: the multiply scattered light is smooth)."""
    n_samples: int = param(128, lo=1)
    """Stratified samples per ray."""
    use_occupancy: bool = param(True)
    """Skip samples in empty cells of an occupancy grid refreshed from the density (as ``voxel``)."""
    occupancy: OccupancyConfig = param(default_factory=OccupancyConfig)
    """The occupancy grid's settings."""
    tv_sigma: float = param(1e-3, lo=0.0)
    """Weight of the total-variation prior on the raw density grid."""
    tv_albedo: float = param(1e-3, lo=0.0)
    """Weight of the total-variation prior on the raw albedo grid."""
    tv_rest: float = param(1e-3, lo=0.0)
    """Weight of the total-variation prior on the remainder grid."""
    lr: float = param(0.1, lo=0.0, lo_open=True)
    """Adam learning rate."""

    def __post_init__(self) -> None:
        if isinstance(self.upsample_steps, list):
            object.__setattr__(self, "upsample_steps", tuple(self.upsample_steps))
        check_fields(self)
        doublings = (self.resolution // self.initial_resolution).bit_length() - 1
        if self.initial_resolution > self.resolution or self.initial_resolution << doublings != self.resolution:
            raise ValueError(f"resolution: must be initial_resolution ({self.initial_resolution}) times a power "
                             f"of 2, got {self.resolution}")
        if len(self.upsample_steps) != doublings or any(b <= a for a, b in zip(self.upsample_steps,
                                                                                 self.upsample_steps[1:])):
            raise ValueError(f"upsample_steps: {self.initial_resolution} -> {self.resolution} takes {doublings} "
                             f"increasing step(s), got {list(self.upsample_steps)}")

    def resolution_at(self, step: int) -> int:
        """Density and albedo resolution at (0-based) ``step``."""
        return self.initial_resolution * 2 ** sum(1 for s in self.upsample_steps if step > s)


def field_config(config: ScatterMethodConfig, spec) -> ScatterFieldConfig:
    """The field's settings for a scene: ``density_channels`` resolved from the spec's extinction, and the
    remainder cut to order 0 where the phase function is isotropic (every higher band is multiplied by
    ``g^l = 0``: parameters nothing reaches)."""
    f = config.field
    channels = config.density_channels or (3 if spec.volume.chromatic else 1)
    f = replace(f, density_channels=channels)
    if _asymmetry(spec) == 0.0:
        f = replace(f, remainder_degree=0, zonal_degree=0)
    return f


def environment_mean(scene: SceneInfo, n: int = 1024) -> tuple[float, float, float]:
    """The background's mean radiance over the sphere (RGB): where the remainder starts, so that the medium's
    colour starts near the light around it rather than darker (a start that made clearing the density the
    fastest way to the images)."""
    with dr.suspend_grad():
        bg = scene.background(to_array3f(mi.Array3f, fibonacci_directions(n)))
        return tuple(float(dr.mean(c)[0]) if dr.width(c) > 1 else float(c[0]) for c in bg)  # type: ignore[return-value]


def _asymmetry(spec) -> float:
    """The phase function's ``g`` (0 for an isotropic one)."""
    return float(getattr(spec.volume.phase, "g", 0.0))


class ScatterModel(OccupancyModel):
    name = "scatter"
    config_type = ScatterMethodConfig
    description = ("knows the lights and the phase function: single scattering through the learned density "
                   "and albedo grids, a learned remainder")
    tiny = MappingProxyType({"resolution": 8, "initial_resolution": 4, "upsample_steps": [3], "rest_resolution": 2,
                             "n_samples": 16, "field": {"shadow_resolution": 4, "shadow_samples": 4}})

    def __init__(self, config: ScatterMethodConfig, scene: SceneInfo, seed: int = 0) -> None:
        from mitsnerf.scene.lights import delta_lights

        spec = scene_spec(scene, self.name, "its spec gives the lights and the phase function")
        self.config = config
        base = ScatterField.create(field_config(config, spec), config.initial_resolution, config.rest_resolution,
                                   mi.TensorXf, scene.box, delta_lights(spec.lights), _asymmetry(spec),
                                   rest_init=environment_mean(scene))
        super().__init__(base, config.occupancy if config.use_occupancy else None, scene, seed, config.n_samples)

    def parameters(self) -> Mapping[str, Any]:
        f = self.base_field
        return {SIGMA_KEY: f.sigma_raw, ALBEDO_KEY: f.albedo_raw, REST_KEY: f.rest}

    def set_parameters(self, values: Mapping[str, Any]) -> None:
        """New grids (the density and albedo ones of one resolution, any: a resumed run may hold upsampled
        ones; the remainder of its configured shape); the shadows are recomputed before the next render."""
        new = {k: values[k] for k in KEYS if k in values}
        if not new:
            return
        f = self.base_field
        current = dict(self.parameters())
        current.update(new)
        r = int(current[SIGMA_KEY].shape[0]) if current[SIGMA_KEY].ndim == 4 else 0
        for key, c in ((SIGMA_KEY, f.config.density_channels), (ALBEDO_KEY, 3)):
            if r < 1 or tuple(current[key].shape) != (r, r, r, c):
                raise ParameterShapeError(key, tuple(current[key].shape), (max(r, 1),) * 3 + (c,))
        if tuple(current[REST_KEY].shape) != tuple(f.rest.shape):
            raise ParameterShapeError(REST_KEY, tuple(current[REST_KEY].shape), tuple(f.rest.shape))
        self.base_field = f.with_grids(**{k: current[k] for k in KEYS})

    @property
    def resolution(self) -> int:
        return self.base_field.resolution

    def _shadowed(self) -> None:
        """Compute the shadows of the current grids once, outside any AD graph (evaluation, export)."""
        if self.base_field.shadows is None:
            with dr.suspend_grad():
                self.base_field = self.base_field.with_shadows()

    def field(self):
        self._shadowed()
        return super().field()

    def render_rays(self, o, d, *, u=None, training: bool = False) -> RenderOutput:
        if training:  # inside this step's AD graph: the loss reaches the density along the shadow rays
            self.base_field = self.base_field.with_shadows()
        else:
            self._shadowed()
        comp = self.composite(o, d, u, training)
        extra = {}
        if training:
            f, cfg = self.base_field, self.config
            for key, weight, grid in (("tv_sigma", cfg.tv_sigma, f.sigma_raw), ("tv_albedo", cfg.tv_albedo,
                                      f.albedo_raw), ("tv_rest", cfg.tv_rest, f.rest)):
                if weight > 0 and grid.shape[0] > 1:
                    extra[key] = weight * total_variation(grid)
        return RenderOutput(comp, extra)

    def after_step(self, step: int, params: Mapping[str, Any]) -> Mapping[str, Any]:
        """The density and albedo grids doubled after a step listed in ``upsample_steps`` (their Adam state
        restarts); the occupancy grid refreshed every ``occupancy.update_every`` steps."""
        new = {}
        if step in self.config.upsample_steps:
            r = self.config.resolution_at(step + 1)
            new = {key: upsample(params[key], r) for key in (SIGMA_KEY, ALBEDO_KEY)}
            self.set_parameters(new)
        super().after_step(step, params)
        return new


#: The method this module declares (:mod:`mitsnerf.methods` registers it as ``scatter``).
METHOD = ScatterModel
