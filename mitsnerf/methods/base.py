"""The interface every method implements, and the data a method trains on.

A method is a frozen config dataclass plus a :class:`Model`: something with named
parameters that ``drjit.opt`` optimises and a differentiable ``render_rays``. The
trainer (:mod:`mitsnerf.train`) owns batching, the optimiser, checkpoints and
evaluation; a method only says how its scene representation renders a ray batch.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
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


@dataclass(frozen=True)
class RenderOutput:
    """A method's rendering of R rays: the composite plus regularisation losses (scalars)."""

    composite: Composite
    extra_losses: Mapping[str, Any] = None  # name -> Float of width 1, added to the loss

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
