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

import mitsuba as mi

from mitsnerf.fields.ngp import NGPConfig, NGPField
from mitsnerf.fields.occupancy import OccupancyConfig
from mitsnerf.methods.base import RenderOutput, SceneInfo, cover_radiance
from mitsnerf.methods.occupancy import OccupancyModel


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
        self.config = config
        ngp = NGPField(cover_radiance(config.network, scene), mi.TensorXf, scene.box, seed)
        super().__init__(ngp, config.occupancy if config.use_occupancy else None, scene, seed, config.n_samples)

    def parameters(self) -> Mapping[str, Any]:
        return self.base_field.params

    def set_parameters(self, values: Mapping[str, Any]) -> None:
        self.base_field.set_parameters(values)

    def render_rays(self, o, d, *, u=None, training: bool = False) -> RenderOutput:
        return RenderOutput(self.composite(o, d, u, training))
