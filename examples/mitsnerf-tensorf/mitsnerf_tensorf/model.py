"""``tensorf``: TensoRF's VM decomposition trained coarse to fine, with L1 and TV priors, as a mitsnerf method.

The field (:class:`mitsnerf_tensorf.field.VMField`) is rendered by the harness's shared renderer with empty
space skipped (:class:`mitsnerf.methods.occupancy.OccupancyModel`, as ``voxel`` and ``ngp``: the same
stratified samples and compositing, the field evaluated only in occupied cells); TensoRF's own skipping is
its alpha mask, a grid of the learned density refreshed at listed steps, which the occupancy grid replaces.

Coarse to fine as TensoRF: the vectors and planes start at ``initial_resolution`` and are resampled after each
step of ``upsample_steps`` to resolutions spaced evenly in log voxel count up to ``resolution``
(TensoRF's ``N_voxel_list``); the resampled tensors replace the optimiser's entries, whose Adam state
restarts (TensoRF resets its optimiser at each upsampling too). The loss adds, as ``extra_losses``::

    l1 * (sum_m mean |M^m_density| + mean |v^m_density|)          TensoRF's density L1 (``L1_weight``)
    tv_density * sum_m TV(M^m_density) + tv_app * sum_m TV(M^m_app)   TensoRF's TV on the planes

with ``TV`` the mean squared neighbour difference of :func:`mitsnerf.fields.voxel.total_variation`. The basis
matrix and the colour MLP learn at ``lr * lr_network_factor`` (TensoRF: 0.02 for the grids, 1e-3 for them).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import drjit as dr
import mitsuba as mi

from mitsnerf.config import check_fields, param
from mitsnerf.fields.occupancy import OccupancyConfig
from mitsnerf.fields.voxel import total_variation
from mitsnerf.methods.base import (
    MethodConfig,
    ParameterShapeError,
    RenderOutput,
    SceneInfo,
    check_shapes,
    cover_radiance,
)
from mitsnerf.methods.occupancy import OccupancyModel
from mitsnerf_tensorf.field import GRID_KEYS, PAIRS, VMField, VMFieldConfig, grid_shape, init_params, resample


@dataclass(frozen=True)
class TensoRFConfig(MethodConfig):
    """Configuration of the ``tensorf`` method."""

    field: VMFieldConfig = param(default_factory=VMFieldConfig)
    """The VM field: components, basis, colour decode, density activation."""
    resolution: int = param(64, lo=2, hi=1024)
    """Final grid resolution (texels per axis of every plane and line)."""
    initial_resolution: int = param(32, lo=2, hi=1024)
    """Resolution at the start."""
    upsample_steps: tuple[int, ...] = param((150, 300), lo=0)
    """Steps (0-based, increasing) after which the grids are resampled; the k-th of n goes to
    ``round(exp(log R_0^3 + k / n (log R^3 - log R_0^3))^(1/3))`` (TensoRF's schedule)."""
    n_samples: int = param(128, lo=1)
    """Stratified samples per ray."""
    use_occupancy: bool = param(True)
    """Skip samples in empty cells of an occupancy grid refreshed from the learned density."""
    occupancy: OccupancyConfig = param(default_factory=OccupancyConfig)
    """The occupancy grid's settings."""
    occupancy_from: int = param(0, lo=0)
    """First step whose end refreshes the occupancy grid (TensoRF starts its alpha mask at step 2000 of 30000);
    before it every sample is evaluated."""
    l1: float = param(0.0, lo=0.0)
    """Weight of the L1 prior on the density vectors and planes (TensoRF: 8e-5). 0 by default: with the density
    shift of -3 a zero feature is a haze of 1.2, not empty space, and on the default cloud the prior cost
    0.7 dB at TensoRF's 8e-5 (shift -5) and 0.2 dB at 4e-6 (shift -3, with TV)."""
    tv_density: float = param(0.02, lo=0.0)
    """Weight of TV on the density planes (TensoRF's LLFF setting: 1 x its 1e-2 factor, x 2 in its TV's scale)."""
    tv_app: float = param(0.02, lo=0.0)
    """Weight of TV on the appearance planes (as ``tv_density``)."""
    lr: float = param(0.02, lo=0.0, lo_open=True)
    """Adam learning rate of the vectors and planes (TensoRF: 0.02)."""
    lr_network_factor: float = param(0.05, lo=0.0, lo_open=True)
    """The basis matrix's and the colour MLP's learning rate as a fraction of ``lr`` (TensoRF: 1e-3 / 0.02)."""

    def __post_init__(self) -> None:
        if isinstance(self.upsample_steps, list):
            object.__setattr__(self, "upsample_steps", tuple(self.upsample_steps))
        check_fields(self)
        if self.initial_resolution > self.resolution:
            raise ValueError(f"initial_resolution, resolution: need initial_resolution <= resolution, "
                             f"got {self.initial_resolution}, {self.resolution}")
        if any(b <= a for a, b in zip(self.upsample_steps, self.upsample_steps[1:])):
            raise ValueError(f"upsample_steps: must be increasing, got {list(self.upsample_steps)}")
        if self.upsample_steps and self.initial_resolution == self.resolution:
            raise ValueError("upsample_steps: initial_resolution equals resolution, nothing to upsample; "
                             "give no steps")
        if not self.upsample_steps and self.initial_resolution != self.resolution:
            raise ValueError(f"upsample_steps: {self.initial_resolution} -> {self.resolution} needs at least one step")

    def resolutions(self) -> tuple[int, ...]:
        """The resolution after each upsampling step (the last is ``resolution``).

        >>> TensoRFConfig(initial_resolution=16, resolution=64, upsample_steps=(10, 20)).resolutions()
        (32, 64)
        """
        n = len(self.upsample_steps)
        lo, hi = 3 * math.log(self.initial_resolution), 3 * math.log(self.resolution)
        return tuple(round(math.exp((lo + (k + 1) / n * (hi - lo)) / 3)) for k in range(n))

    def resolution_at(self, step: int) -> int:
        """Grid resolution used at (0-based) ``step``.

        >>> TensoRFConfig(initial_resolution=16, resolution=64, upsample_steps=(10, 20)).resolution_at(15)
        32
        """
        done = sum(1 for s in self.upsample_steps if step > s)
        return self.resolutions()[done - 1] if done else self.initial_resolution


class TensoRFModel(OccupancyModel):
    """TensoRF-VM (see the module docstring); parameters: the planes and lines by :data:`GRID_KEYS`, ``basis``,
    and ``mlp.{l}.weights|bias`` for the ``mlp`` decode."""

    name = "tensorf"
    config_type = TensoRFConfig
    description = "TensoRF vector-matrix decomposition (example plugin), L1 + TV, coarse to fine"
    tiny = MappingProxyType({"field": {"density_components": 2, "app_components": 2}, "l1": 1e-5,
                             "resolution": 8, "initial_resolution": 4, "upsample_steps": [3], "n_samples": 16,
                             "occupancy": {"resolution": 8, "update_every": 2}})

    def __init__(self, config: TensoRFConfig, scene: SceneInfo, seed: int = 0) -> None:
        self.config = config
        field_config = cover_radiance(config.field, scene)
        params = init_params(field_config, config.initial_resolution, mi.TensorXf, seed)
        super().__init__(VMField(field_config, params, scene.box), config.occupancy if config.use_occupancy else None,
                         scene, seed, config.n_samples)

    def parameters(self) -> Mapping[str, Any]:
        return self.base_field.params

    def set_parameters(self, values: Mapping[str, Any]) -> None:
        """New values for (a subset of) the parameters. The planes and lines may come at another resolution
        (a resumed run holds resampled ones), but all of them at one; the rest keep their shapes (else a
        :class:`~mitsnerf.methods.base.ParameterShapeError`)."""
        current = self.base_field.params
        merged = {key: values[key] if key in values else current[key] for key in current}
        unknown = sorted(k for k in values if k not in current)
        if unknown:
            raise KeyError(f"tensorf: unknown parameters {unknown}")
        r = int(merged["density.line.x"].shape[0])
        for key in GRID_KEYS:
            want = grid_shape(key, r, current[key].shape[-1])
            if tuple(merged[key].shape) != want:
                raise ParameterShapeError(key, tuple(merged[key].shape), want)
        check_shapes(current, {k: v for k, v in values.items() if k not in GRID_KEYS})
        self.base_field = VMField(self.base_field.config, merged, self.scene.box)

    @property
    def resolution(self) -> int:
        return self.base_field.resolution

    def lr_scales(self, step: int) -> Mapping[str, float]:
        f = self.config.lr_network_factor
        return {} if f == 1.0 else {k: f for k in self.base_field.params if k not in GRID_KEYS}

    def regularisers(self) -> dict:
        """The priors' terms (Float of width 1 each), as weighted in the loss."""
        c, params = self.config, self.base_field.params
        out = {}
        if c.l1 > 0:
            l1 = sum(dr.mean(dr.abs(params[k].array)) for k in GRID_KEYS if k.startswith("density."))
            out["l1_density"] = c.l1 * l1
        for kind, weight in (("density", c.tv_density), ("app", c.tv_app)):
            if weight > 0:
                tv = sum(total_variation(_as_volume(params[f"{kind}.plane.{p}"])) for p, _, _, _ in PAIRS)
                out[f"tv_{kind}"] = weight * tv
        return out

    def render_rays(self, o, d, *, u=None, training: bool = False) -> RenderOutput:
        comp = self.composite(o, d, u, training)
        return RenderOutput(comp, self.regularisers() if training else {})

    def after_step(self, step: int, params: Mapping[str, Any]) -> Mapping[str, Any]:
        """The planes and lines resampled after a step of ``upsample_steps`` (new shapes: the optimiser
        restarts their Adam state); the occupancy grid refreshed every ``occupancy.update_every`` steps
        from step ``occupancy_from`` on."""
        new = {}
        if step in self.config.upsample_steps:
            r = self.config.resolution_at(step + 1)
            new = {key: resample(params[key], r) for key in GRID_KEYS}
            self.set_parameters(new)
        if step >= self.config.occupancy_from:
            super().after_step(step, params)
        return new


def _as_volume(plane):
    """A plane (R, R, C) as the (1, R, R, C) grid :func:`~mitsnerf.fields.voxel.total_variation` takes (its
    first axis of one texel adds no term)."""
    return dr.reshape(type(plane), plane, (1, *plane.shape))
