"""The per-ray model of one field with empty-space skipping, shared by ``ngp`` and ``voxel``.

Rays get the same stratified samples and compositing as every method
(:func:`mitsnerf.render.skipping.render_rays_skipping`, or with ``replay`` the same as one loop per ray whose
gradient is replayed, :func:`mitsnerf.render.replay.render_rays_replay`); an occupancy grid
(:mod:`mitsnerf.fields.occupancy`) keeps the samples in occupied cells whose estimated
transmittance is above ``early_stop_T``, and only those reach the field. The grid is refreshed
from the field's density every ``update_every`` steps (seeded by the run's seed and the step, so
a resumed run updates exactly as an uninterrupted one) and checkpointed with the parameters.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import drjit as dr
import mitsuba as mi

from mitsnerf.fields.occupancy import OccupancyConfig, OccupancyGrid, OccupancyMaskedField
from mitsnerf.math.composite import Composite
from mitsnerf.methods.base import RayModel, SceneInfo
from mitsnerf.render.replay import render_rays_replay
from mitsnerf.render.skipping import render_rays_skipping
from mitsnerf.render.volume import render_rays


class OccupancyModel(RayModel):
    """A :class:`RayModel` of ``base_field`` with an optional occupancy grid (``occupancy`` None: none)."""

    def __init__(self, base_field, occupancy: OccupancyConfig | None, scene: SceneInfo, seed: int,
                 n_samples: int, replay: bool = False) -> None:
        self.base_field = base_field
        self.replay = replay
        """Render through :func:`mitsnerf.render.replay.render_rays_replay` (the same samples, compositing and
        skipping; the gradient replayed per ray) instead of the R x N arrays of the shared renderer."""
        """The field as parameterised (density everywhere, also in cells the grid skips)."""
        self.scene = scene
        self.seed = seed
        self.n_samples = n_samples
        self.grid = OccupancyGrid(occupancy, mi.Float, scene.box) if occupancy is not None else None
        self.active_fraction = 1.0
        """Share of the last training batch's samples that reached the field (a diagnostic)."""

    def samples_per_ray(self) -> int:
        return self.n_samples

    def field(self):
        """The field as trained: density 0 in cells the occupancy grid skips."""
        return self.base_field if self.grid is None else OccupancyMaskedField(self.base_field, self.grid)

    def loop_field(self):
        """:attr:`base_field` as a symbolic loop can evaluate it (:attr:`replay`); the field itself by default."""
        return self.base_field

    def composite(self, o, d, u=None, training: bool = False) -> Composite:
        """The rays rendered through :attr:`base_field`, skipping what the grid marks empty."""
        scene = self.scene
        if self.replay:
            stats: dict = {}
            comp = render_rays_replay(self.loop_field(), o, d, self.n_samples, box=scene.box, u=u,
                                      background=scene.background, grid=self.grid, params=dict(self.parameters()),
                                      stats=stats)
            if training and self.grid is not None:
                self.active_fraction = int(dr.sum(stats["kept"])[0]) / max(dr.width(o) * self.n_samples, 1)
            return comp
        if self.grid is None:
            return render_rays(self.base_field, o, d, self.n_samples, box=scene.box, u=u, background=scene.background)
        comp, mask = render_rays_skipping(self.base_field, self.grid, o, d, self.n_samples, box=scene.box, u=u,
                                          background=scene.background)
        if training:
            self.active_fraction = int(dr.count(mask)[0]) / max(dr.width(mask), 1)
        return comp

    def after_step(self, step: int, params: Mapping[str, Any]) -> Mapping[str, Any]:
        """Refresh the occupancy grid every ``update_every`` steps; no parameter changes."""
        if self.grid is not None and (step + 1) % self.grid.config.update_every == 0:
            self.grid.update(self.base_field.density, self.seed, step)
        return {}

    def extra_state(self) -> dict:
        return self.grid.state() if self.grid is not None else {}

    def load_extra_state(self, state: Mapping) -> None:
        if self.grid is not None and "occupancy.rho" in state:
            self.grid.load_state(state)
