"""The interface every method implements, and the data a method trains on.

A method is a frozen config dataclass plus a :class:`Model`: something with named
parameters that ``drjit.opt`` optimises and a differentiable ``render_rays``. The
trainer (:mod:`mitsnerf.train`) owns batching, the optimiser, checkpoints and
evaluation; a method only says how its scene representation renders a ray batch.

Methods that do not fit per-ray rendering (``mitsuba-inverse`` renders whole images
through Mitsuba's path tracer) override two optional hooks instead:
:meth:`Model.training_loss` (their own step's loss; the trainer still owns the
optimiser, NaN/divergence checks and checkpoints) and :meth:`Model.render_view` (a whole
camera, used by :func:`mitsnerf.evaluate.render_camera`). :meth:`Model.lr_scales`
scales the scheduled learning rate per parameter (e.g. halved after each upsampling).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, replace
from typing import Any, Callable, ClassVar, Mapping

import drjit as dr

from mitsnerf.math.composite import Composite


@dataclass(frozen=True)
class SceneInfo:
    """What a method may know about the scene before training (never the test images)."""

    box_min: tuple[float, float, float]
    box_max: tuple[float, float, float]
    background: Callable[[Any], Any]
    """``d -> Array3f`` radiance behind the medium."""
    radiance_max: float
    """Largest training pixel value (for output scalings)."""
    manifest: Mapping[str, Any] | None = None
    """The dataset's ``manifest.json`` (None for foreign data): its ``spec`` gives lights and
    medium placement to physically based methods."""


@dataclass(frozen=True)
class StepLoss:
    """A model's own training objective for one step (see :meth:`Model.training_loss`)."""

    loss: Any
    """Float of width 1, differentiable with respect to the optimised parameters."""
    mse: Any
    """Float of width 1: the image error, for the logged PSNR."""
    rays: int
    """Camera rays traced this step (for the rays/s figure)."""


@dataclass(frozen=True)
class RenderOutput:
    """A method's rendering of R rays: the composite plus regularisation losses (scalars)."""

    composite: Composite
    extra_losses: Mapping[str, Any] = None  # name -> Float of width 1, added to the loss
    aux_rgb: Mapping[str, Any] = None
    """name -> Array3f (R,): further colour predictions of the same rays, each supervised by
    the same photometric MSE as ``rgb`` and added to the loss (NeRF's coarse pass)."""

    @property
    def rgb(self):
        return self.composite.rgb


class Model(ABC):
    """A trainable scene representation.

    ``parameters()`` maps names to Dr.Jit tensors/arrays; the trainer registers them
    with an optimiser once and, after each step, hands the optimiser back through
    ``set_parameters`` (the optimiser is the source of truth during training).
    """

    name: ClassVar[str]

    @abstractmethod
    def parameters(self) -> Mapping[str, Any]:
        """Every trainable value, by dotted name."""

    @abstractmethod
    def set_parameters(self, values: Mapping[str, Any]) -> None:
        """Take new values for (a subset of) the parameters, e.g. from the optimiser."""

    @abstractmethod
    def render_rays(self, o, d, *, u=None, training: bool = False) -> RenderOutput:
        """Render rays ``o + t d`` (Array3f (R,)); ``u`` is Float jitter (training) or None."""

    def samples_per_ray(self) -> int:
        """Field evaluations per ray (for samples/s figures)."""
        return 0

    def jitter_size(self) -> int:
        """Uniform numbers per ray the model's sampler wants in ``u`` (0: none)."""
        return self.samples_per_ray()

    def on_step(self, step: int, opt) -> None:
        """Hook after each optimiser step (coarse-to-fine, occupancy updates, ...)."""

    def training_loss(self, data, step: int, rng) -> StepLoss | None:
        """This step's objective, for methods that do not train on random ray batches.

        ``data`` is the :class:`mitsnerf.train.PixelData` (``data.images`` (V, H, W, 3),
        ``data.cameras``), ``rng`` the step's generator (a pure function of seed and step,
        so resumed runs draw the same). Return None (the default) for the trainer's own
        ray-batch step through :meth:`render_rays`.
        """
        return None

    def render_view(self, camera, pixel_center: float = 0.5):
        """A whole camera as a :class:`mitsnerf.evaluate.Rendered`, or None (the default)
        to render it ray by ray through :meth:`render_rays`."""
        return None

    def lr_scales(self, step: int) -> Mapping[str, float]:
        """Per-parameter factors on the scheduled learning rate at ``step`` (missing: 1).

        A pure function of the step, so a resumed run schedules exactly as an uninterrupted one.
        """
        return {}

    def field(self):
        """The field callable ``(x, d) -> (rgb, sigma)`` (for export and the plugin)."""
        raise NotImplementedError(f"{type(self).__name__} has no queryable field")

    def extra_state(self) -> dict:
        """Non-parameter state to checkpoint (numpy-convertible)."""
        return {}

    def load_extra_state(self, state: Mapping) -> None:
        """Restore what :meth:`extra_state` returned."""


def num_parameters(params: Mapping[str, Any]) -> int:
    """Total number of scalar parameters."""
    return int(sum(dr.prod(v.shape) if hasattr(v, "shape") and v.shape else dr.width(v) for v in params.values()))


def cover_radiance(field_config, scene: SceneInfo):
    """``field_config`` with ``c_max`` (the largest colour its head can output) raised to
    ``max(1, 1.25 x scene.radiance_max)`` when the training images are brighter than it."""
    if field_config.c_max < scene.radiance_max:
        return replace(field_config, c_max=max(1.0, 1.25 * scene.radiance_max))
    return field_config


class OccupancyModel(Model):
    """A model of a field ``self._field`` that skips empty space with ``self.grid`` (an
    :class:`mitsnerf.fields.occupancy.OccupancyGrid`, or None).

    Updates the grid from the field's density every ``update_every`` steps (seeded by
    ``self.seed`` and the step), checkpoints it with the parameters, and exposes the field as
    trained (density 0 in skipped cells). Subclasses that override :meth:`on_step` call this one.
    """

    _field: Any = None
    grid: Any = None
    seed: int = 0

    def field(self):
        """The field as trained: density 0 in cells the occupancy grid skips."""
        from mitsnerf.fields.occupancy import OccupancyMaskedField

        return self._field if self.grid is None else OccupancyMaskedField(self._field, self.grid)

    def on_step(self, step: int, opt) -> None:
        if self.grid is not None and (step + 1) % self.grid.config.update_every == 0:
            self.grid.update(self._field.density, self.seed, step)

    def extra_state(self) -> dict:
        return self.grid.state() if self.grid is not None else {}

    def load_extra_state(self, state: Mapping) -> None:
        if self.grid is not None and "occupancy.rho" in state:
            self.grid.load_state(state)
