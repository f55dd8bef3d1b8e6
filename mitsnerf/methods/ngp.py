"""``ngp``: a hash-grid field (instant-ngp) with an occupancy grid that skips empty space.

Rendered by :func:`mitsnerf.render.skipping.render_rays_skipping`: each ray gets the
same stratified samples as every method (:func:`mitsnerf.render.volume.sample_rays`); the occupancy grid
(:mod:`mitsnerf.fields.occupancy`) keeps only those in occupied cells whose
estimated transmittance is above ``early_stop_T``; the field is evaluated on those
alone and the samples are composited by :func:`mitsnerf.math.composite.composite`,
skipped ones with ``sigma = 0``. The grid is refreshed from the field's density
every ``occupancy.update_every`` steps.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

import drjit as dr
import mitsuba as mi

from mitsnerf.fields.ngp import NGPConfig, NGPField
from mitsnerf.fields.occupancy import OccupancyConfig, OccupancyGrid
from mitsnerf.methods.base import OccupancyModel, RenderOutput, SceneInfo, cover_radiance
from mitsnerf.render.skipping import render_rays_skipping


@dataclass(frozen=True)
class NGPMethodConfig:
    """Configuration of the ``ngp`` method.

    | name          | type            | default | meaning                                        |
    |---------------|-----------------|---------|------------------------------------------------|
    | network       | NGPConfig       |         | hash grid and MLP sizes                        |
    | occupancy     | OccupancyConfig |         | occupancy grid (resolution, updates, threshold)|
    | use_occupancy | bool            | true    | skip empty space and stop rays early           |
    | n_samples     | int             | 128     | stratified samples per ray before skipping     |
    | lr            | float           | 1e-2    | Adam learning rate (instant-ngp's)             |
    """

    network: NGPConfig = field(default_factory=NGPConfig)
    occupancy: OccupancyConfig = field(default_factory=OccupancyConfig)
    use_occupancy: bool = True
    n_samples: int = 128
    lr: float = 1e-2

    def __post_init__(self) -> None:
        if self.n_samples < 1:
            raise ValueError(f"n_samples: must be >= 1, got {self.n_samples}")
        if not self.lr > 0:
            raise ValueError(f"lr: must be > 0, got {self.lr}")


class NGPModel(OccupancyModel):
    name = "ngp"

    def __init__(self, config: NGPMethodConfig, scene: SceneInfo, seed: int = 0) -> None:
        field_config = cover_radiance(config.network, scene)
        self.config = config
        self.scene = scene
        self.seed = seed
        self._field = NGPField(field_config, mi.TensorXf, seed, scene.box_min, scene.box_max)
        self.grid = OccupancyGrid(config.occupancy, mi.Float, scene.box_min, scene.box_max) if config.use_occupancy else None
        self.active_fraction = 1.0
        """Share of the last batch's samples that reached the network (a diagnostic)."""

    def parameters(self) -> Mapping[str, Any]:
        return self._field.parameters()

    def set_parameters(self, values: Mapping[str, Any]) -> None:
        self._field.set_parameters(values)

    def samples_per_ray(self) -> int:
        return self.config.n_samples

    def render_rays(self, o, d, *, u=None, training: bool = False) -> RenderOutput:
        comp, mask = render_rays_skipping(
            self._field, self.grid, o, d, self.config.n_samples, u=u, background=self.scene.background,
            box_min=self.scene.box_min, box_max=self.scene.box_max,
        )
        if training:
            self.active_fraction = int(dr.count(mask)[0]) / max(dr.width(mask), 1)
        return RenderOutput(comp, {})
