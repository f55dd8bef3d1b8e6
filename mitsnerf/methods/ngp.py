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

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import mitsuba as mi

from mitsnerf.config import check_fields, param
from mitsnerf.errors import SpecError
from mitsnerf.fields.ngp import NGPConfig, NGPField
from mitsnerf.fields.occupancy import OccupancyConfig
from mitsnerf.methods.base import MethodConfig, RenderOutput, SceneInfo, check_shapes, cover_radiance
from mitsnerf.methods.occupancy import OccupancyModel


@dataclass(frozen=True)
class NGPMethodConfig(MethodConfig):
    """Configuration of the ``ngp`` method."""

    network: NGPConfig = param(default_factory=NGPConfig)
    """Hash grid and MLP sizes."""
    occupancy: OccupancyConfig = param(default_factory=OccupancyConfig)
    """The occupancy grid (resolution, updates, threshold)."""
    use_occupancy: bool = param(True)
    """Skip empty space and stop rays early."""
    n_samples: int = param(128, lo=1)
    """Stratified samples per ray before skipping."""
    replay: bool = param(False)
    """Render through the replayed march (:func:`mitsnerf.render.replay.render_rays_replay`): the same samples,
    skipping and compositing as one loop per ray, the MLPs on cooperative vectors (:meth:`NGPField.loop_field
    <mitsnerf.fields.ngp.NGPField.loop_field>`), the gradient replayed, nothing of size rays x samples stored.
    Off: on this CPU it ran 0.28x the steps per second (the MLPs run per SIMD packet of rays for every sample
    any of them keeps, where the shared renderer multiplies matrices over the compacted kept samples alone)."""
    lr: float = param(1e-2, lo=0.0, lo_open=True)
    """Adam learning rate (instant-ngp's)."""

    def __post_init__(self) -> None:
        check_fields(self)
        if self.network.density_channels == 3 and self.replay:
            raise ValueError("replay: the replayed march carries one extinction per ray; with "
                             "network.density_channels = 3 set replay = false")


class NGPModel(OccupancyModel):
    name = "ngp"
    config_type = NGPMethodConfig
    description = "hash-grid encoding, tiny MLPs, occupancy-grid skipping"
    tiny = MappingProxyType({"network": {"n_levels": 2, "log2_hashmap_size": 10, "base_resolution": 8,
                                         "max_resolution": 16, "hidden": 8, "color_hidden": 8},
                             "occupancy": {"resolution": 8, "update_every": 2}, "n_samples": 16})

    def __init__(self, config: NGPMethodConfig, scene: SceneInfo, seed: int = 0) -> None:
        self.config = config
        ngp = NGPField(cover_radiance(config.network, scene), mi.TensorXf, scene.box, seed)
        if config.replay and (why := ngp.loop_refusal()) is not None:
            raise SpecError(None, "replay", f"the replayed march cannot run here: {why}; set "
                                            "network.network_path = coopvec-fp16, or replay = false")
        super().__init__(ngp, config.occupancy if config.use_occupancy else None, scene, seed, config.n_samples,
                         replay=config.replay)

    def parameters(self) -> Mapping[str, Any]:
        return self.base_field.params

    def set_parameters(self, values: Mapping[str, Any]) -> None:
        """New values of the field's parameters, each of the shape the config builds (they never change shape)."""
        check_shapes(self.base_field.params, values)
        self.base_field.set_parameters(values)

    def loop_field(self):
        return self.base_field.loop_field()

    def render_rays(self, o, d, *, u=None, training: bool = False) -> RenderOutput:
        return RenderOutput(self.composite(o, d, u, training))


#: The method this module declares (:mod:`mitsnerf.methods` registers it as ``ngp``).
METHOD = NGPModel
