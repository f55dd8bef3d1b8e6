"""``voxel``: a dense density + SH-colour grid, trained coarse to fine with a total-variation prior.

The field (:class:`mitsnerf.fields.voxel.VoxelField`) is rendered by the shared
emission-absorption renderer (:func:`mitsnerf.render.volume.render_rays`), like the
ground truth, or, with ``use_occupancy``, by the same samples and compositing with
empty space skipped (:func:`mitsnerf.render.skipping.render_rays_skipping`): the
backward pass scatters every evaluated sample into 8 voxels x 13 channels, the largest
cost of a step (at 64^3, 4096 rays: 386 ms per step without skipping, 159 ms with it,
on the loaded 2-core machine). With ``replay`` (the default) the same samples, skipping and
compositing run as one loop per ray whose gradient is replayed
(:func:`mitsnerf.render.replay.render_rays_replay`): nothing of size rays x samples is stored
and the grids' gradients are scattered without atomics. The loss adds ``tv_sigma * TV(s) + tv_sh * TV(k)`` (as
``extra_losses``) to the photometric MSE.

On the default cloud (64 spp training views), 60 s of 4096-ray steps reached 45.0 dB
test PSNR (36.5 dB on medium pixels; 1002 steps); SH degree 0 ran 1.8x more steps and
reached 44.4 dB (35.9). Training starts at ``initial_resolution`` and doubles the grids
(trilinearly, :func:`mitsnerf.fields.voxel.upsample`) after each step listed in
``upsample_steps`` until ``resolution``; the upsampled grids replace the optimiser's
entries (their Adam state restarts). The settings are :class:`VoxelMethodConfig`'s fields.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import mitsuba as mi

from mitsnerf.config import check_fields, param
from mitsnerf.fields.occupancy import OccupancyConfig
from mitsnerf.fields.voxel import VoxelField, VoxelFieldConfig, total_variation, upsample
from mitsnerf.methods.base import MethodConfig, ParameterShapeError, RenderOutput, SceneInfo, cover_radiance
from mitsnerf.methods.occupancy import OccupancyModel

SIGMA_KEY = "sigma_raw"
SH_KEY = "sh"


@dataclass(frozen=True)
class VoxelMethodConfig(MethodConfig):
    """Configuration of the ``voxel`` method."""

    grid: VoxelFieldConfig = param(default_factory=VoxelFieldConfig)
    """What each voxel holds: SH degree, activations, initial density."""
    resolution: int = param(64, lo=2, hi=512)
    """Final grid resolution R (voxels per axis)."""
    initial_resolution: int = param(32, lo=2, hi=512)
    """Resolution at the start; doubled after each of ``upsample_steps`` until ``resolution``."""
    upsample_steps: tuple[int, ...] = param((150,), lo=0)
    """Steps (0-based, increasing) after which the grids are doubled; one per doubling needed."""
    n_samples: int = param(128, lo=1)
    """Stratified samples per ray."""
    use_occupancy: bool = param(True, since=("0.1.0+1b73495", False))
    """Skip samples in empty cells of an occupancy grid refreshed from the voxel density (as ngp)."""
    occupancy: OccupancyConfig = param(default_factory=OccupancyConfig)
    """The occupancy grid's settings."""
    replay: bool = param(True)
    """Render through the replayed march (:func:`mitsnerf.render.replay.render_rays_replay`): the same samples,
    skipping and compositing as one loop per ray, its gradient replayed and scattered into the grids, nothing of
    size rays x samples stored; the same losses to float round-off (4e-7 over 300 steps), 1.07x the steps per
    second at 64^3 and 1.01x at 32^3 on the default cloud, more where more samples reach the field (1.35x at
    64^3 with 16% of them) (docs/notes/throughput.md, "Training at the march's pace: the replayed gradient").
    False: the shared renderer's R x N arrays."""
    tv_sigma: float = param(1e-3, lo=0.0)
    """Weight of the total-variation prior on the raw density grid."""
    tv_sh: float = param(1e-3, lo=0.0)
    """Weight of the total-variation prior on the SH coefficient grid."""
    lr: float = param(0.3, lo=0.0, lo_open=True)
    """Adam learning rate."""
    lr_sh_factor: float = param(1.0, lo=0.0, lo_open=True)
    """The SH grid's learning rate as a fraction of the scheduled one."""

    def __post_init__(self) -> None:
        if isinstance(self.upsample_steps, list):
            object.__setattr__(self, "upsample_steps", tuple(self.upsample_steps))
        check_fields(self)
        if self.initial_resolution > self.resolution:
            raise ValueError(f"initial_resolution, resolution: need initial_resolution <= resolution, "
                             f"got {self.initial_resolution}, {self.resolution}")
        doublings = (self.resolution // self.initial_resolution).bit_length() - 1
        if self.initial_resolution << doublings != self.resolution:
            raise ValueError(
                f"resolution: must be initial_resolution ({self.initial_resolution}) times a power of 2, "
                f"got {self.resolution}"
            )
        if len(self.upsample_steps) != doublings:
            raise ValueError(
                f"upsample_steps: {self.initial_resolution} -> {self.resolution} takes {doublings} doubling(s), "
                f"got {len(self.upsample_steps)} step(s) {list(self.upsample_steps)}"
            )
        if any(b <= a for a, b in zip(self.upsample_steps, self.upsample_steps[1:])):
            raise ValueError(f"upsample_steps: must be increasing, got {list(self.upsample_steps)}")
        if self.grid.density_channels == 3 and self.replay:
            raise ValueError("replay: the replayed march carries one extinction per ray; with "
                             "grid.density_channels = 3 set replay = false")

    def resolution_at(self, step: int) -> int:
        """Grid resolution used at (0-based) ``step``.

        >>> VoxelMethodConfig(resolution=128, initial_resolution=32, upsample_steps=(10, 20)).resolution_at(15)
        64
        """
        return self.initial_resolution * 2 ** sum(1 for s in self.upsample_steps if step > s)


def _check_grids(sigma, sh, channels: int, density_channels: int = 1) -> None:
    """Both grids cubes of one resolution ``R``: sigma ``(R, R, R, density_channels)``, sh ``(R, R, R, channels)``."""
    r = int(sigma.shape[0]) if len(sigma.shape) else 0
    for key, grid, c in ((SIGMA_KEY, sigma, density_channels), (SH_KEY, sh, channels)):
        if r < 1 or tuple(grid.shape) != (r, r, r, c):
            raise ParameterShapeError(key, tuple(grid.shape), (max(r, 1),) * 3 + (c,))


class VoxelModel(OccupancyModel):
    name = "voxel"
    config_type = VoxelMethodConfig
    description = "dense density + SH grid, TV prior, coarse to fine"
    tiny = MappingProxyType({"resolution": 8, "initial_resolution": 4, "upsample_steps": [3], "n_samples": 16})

    def __init__(self, config: VoxelMethodConfig, scene: SceneInfo, seed: int = 0) -> None:
        self.config = config
        grids = VoxelField.create(cover_radiance(config.grid, scene), config.initial_resolution, mi.TensorXf, scene.box)
        super().__init__(grids, config.occupancy if config.use_occupancy else None, scene, seed, config.n_samples,
                         replay=config.replay)

    def parameters(self) -> Mapping[str, Any]:
        return {SIGMA_KEY: self.base_field.sigma_raw, SH_KEY: self.base_field.sh}

    def set_parameters(self, values: Mapping[str, Any]) -> None:
        """Take new grids (any resolution: a resumed run may hold upsampled ones), both shaped
        ``(R, R, R, C)`` with the same ``R`` and the channels of the config (else a ParameterShapeError)."""
        sigma = values[SIGMA_KEY] if SIGMA_KEY in values else None
        sh = values[SH_KEY] if SH_KEY in values else None
        if sigma is not None or sh is not None:
            field = self.base_field
            _check_grids(
                field.sigma_raw if sigma is None else sigma, field.sh if sh is None else sh, field.sh.shape[-1],
                self.config.grid.density_channels,
            )
            self.base_field = self.base_field.with_grids(sigma, sh)

    @property
    def resolution(self) -> int:
        return self.base_field.resolution

    def lr_scales(self, step: int) -> Mapping[str, float]:
        return {SH_KEY: self.config.lr_sh_factor} if self.config.lr_sh_factor != 1.0 else {}

    def render_rays(self, o, d, *, u=None, training: bool = False) -> RenderOutput:
        comp = self.composite(o, d, u, training)
        extra = {}
        if training:
            if self.config.tv_sigma > 0:
                extra["tv_sigma"] = self.config.tv_sigma * total_variation(self.base_field.sigma_raw)
            if self.config.tv_sh > 0:
                extra["tv_sh"] = self.config.tv_sh * total_variation(self.base_field.sh)
        return RenderOutput(comp, extra)

    def after_step(self, step: int, params: Mapping[str, Any]) -> Mapping[str, Any]:
        """Both grids doubled after a step listed in ``upsample_steps`` (a new shape: the
        optimiser restarts their Adam state); the occupancy grid refreshed every
        ``occupancy.update_every`` steps."""
        new = {}
        if step in self.config.upsample_steps:
            r = self.config.resolution_at(step + 1)
            new = {key: upsample(params[key], r) for key in (SIGMA_KEY, SH_KEY)}
            self.set_parameters(new)
        super().after_step(step, params)
        return new


#: The method this module declares (:mod:`mitsnerf.methods` registers it as ``voxel``).
METHOD = VoxelModel
