"""``nerf``: a positional-encoding MLP field rendered by stratified emission-absorption quadrature."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

import mitsuba as mi

from mitsnerf.fields.nerf import NeRFConfig, NeRFField
from mitsnerf.methods.base import Model, RenderOutput, SceneInfo
from mitsnerf.render.volume import render_rays


@dataclass(frozen=True)
class NeRFMethodConfig:
    """Configuration of the ``nerf`` method."""

    network: NeRFConfig = field(default_factory=NeRFConfig)
    n_samples: int = 64
    """Stratified samples per ray (N)."""
    lr: float = 5e-3
    """Adam learning rate."""

    def __post_init__(self) -> None:
        if self.n_samples < 1:
            raise ValueError(f"n_samples: must be >= 1, got {self.n_samples}")
        if not self.lr > 0:
            raise ValueError(f"lr: must be > 0, got {self.lr}")


class NeRFModel(Model):
    name = "nerf"

    def __init__(self, config: NeRFMethodConfig, scene: SceneInfo, seed: int = 0) -> None:
        net_config = config.network
        if net_config.c_max < scene.radiance_max:
            from dataclasses import replace

            net_config = replace(net_config, c_max=max(1.0, 1.25 * scene.radiance_max))
        self.config = config
        self.scene = scene
        self._field = NeRFField.create(net_config, mi.TensorXf, seed, scene.box_min, scene.box_max)

    def parameters(self) -> Mapping[str, Any]:
        return dict(self._field.net.items())

    def set_parameters(self, values: Mapping[str, Any]) -> None:
        for key, value in values.items():
            self._field.net[key] = value

    def samples_per_ray(self) -> int:
        return self.config.n_samples

    def field(self):
        return self._field

    def render_rays(self, o, d, *, u=None, training: bool = False) -> RenderOutput:
        comp = render_rays(
            self._field, o, d, self.config.n_samples, u=u, background=self.scene.background,
            box_min=self.scene.box_min, box_max=self.scene.box_max,
        )
        return RenderOutput(comp, {})
