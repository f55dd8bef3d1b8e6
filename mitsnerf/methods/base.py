"""What a method is, for the built-ins and for a plugin alike: the contract the harness holds every method to.

A method is a :class:`Model` subclass with three class attributes and a constructor:

- ``config_type``: a frozen dataclass subclassing :class:`MethodConfig` (so it has ``lr``), every field
  with a default (:func:`mitsnerf.config.param`, a docstring under each field): what ``--set`` and a bench
  file's ``config`` table set, validated by :func:`mitsnerf.config.from_dict`;
- ``description``: one line for ``mitsnerf methods``;
- ``tiny``: overrides of ``config_type`` that make the method's smallest configuration (the
  conformance suite, ``mitsnerf methods --check``, trains it for a few steps on a tiny dataset);
- ``__init__(self, config, scene: SceneInfo, seed: int)``: the model for one scene, initialised
  from ``seed`` alone (a run resumed or repeated with the same seed starts from the same values).

and renders through one of three narrow capabilities:

- :class:`RendersRays` (subclass :class:`RayModel`), a per-ray model: it writes
  :meth:`RayModel.render_rays` (and says how much jitter its sampler draws). The trainer's step is a
  random batch of training pixels rendered through it; whole views are rendered ray by ray by the base class.
- :class:`TrainsOnPixels` (subclass :class:`PixelModel`), a model with its own estimator: it writes its step's
  loss over the trainer's ``batch_rays`` training pixels (:meth:`PixelModel.pixel_batch_loss`) and
  :meth:`PixelModel.render_view` (``mitsuba-inverse`` traces the pixels' paths and renders whole images
  through Mitsuba's path tracer).
- :class:`TrainsOnViews` (subclass :class:`ViewModel`), a whole-view model: it writes its own step's loss
  (:meth:`ViewModel.training_loss`) and :meth:`ViewModel.render_view`.

The trainer (:mod:`mitsnerf.train`) picks the step by protocol and owns the optimiser,
checkpoints and the schedules. Parameters are a mapping (a ``drjit.nn`` module or a plain dict)
that ``drjit.opt`` optimisers take as is; after every step the trainer hands the optimiser's
values back through :meth:`Model.set_parameters`. A model changes its parameters only by
returning new values from :meth:`Model.after_step`, which the trainer writes into the optimiser
(coarse to fine, clamping): schedules return values, they never rewrite the optimiser. A value of
a new shape restarts its optimiser state, unless the model returns :class:`Rows` saying which old row
each new row continues (primitives added and removed): the trainer then carries those rows' state.

A capability beyond rendering is a protocol of its own, tested with ``isinstance``: :class:`HasField`, a
model whose learned medium can be queried (``field()``; with ``density(x)`` the density scores and
``mitsnerf export`` read it); :class:`FollowsBudget`, a model whose schedules are fractions of the run's step
budget (the trainer calls ``set_budget(steps)`` before the first step).

A method joins the registry (:mod:`mitsnerf.methods`) by declaring itself in its own module
(``METHOD = NeRFModel``, the built-ins), by a ``mitsnerf.methods`` entry point, or by the
``MITSNERF_METHODS`` variable (:mod:`mitsnerf.plugins`).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Any, ClassVar, Protocol, runtime_checkable

import drjit as dr

from mitsnerf.config import param
from mitsnerf.fields.protocols import Field
from mitsnerf.math.box import Box
from mitsnerf.math.composite import Composite
from mitsnerf.render.camera import Rendered, render_view


@dataclass(frozen=True)
class SceneInfo:
    """What a method may know about the scene before training (never the test images)."""

    box: Box
    """The dataset's scene box: every field and grid maps it."""
    background: Callable[[Any], Any]
    """``d -> Array3f`` radiance behind the medium."""
    radiance_max: float
    """Largest training pixel value (for output scalings)."""
    manifest: Mapping[str, Any] | None = None
    """The dataset's ``manifest.json`` (None for foreign data): its ``spec`` gives lights and
    medium placement to physically based methods."""
    train_views: Any = None
    """The training views (``images`` (V, H, W, 3) linear RGB, ``cameras``, ``pixel_center``: the dataset's
    :class:`~mitsnerf.data.dataset.Views`), for what a method builds from them before its first step (an
    emptiness mask, :mod:`mitsnerf.math.carve`); None where the caller gives none."""


@dataclass(frozen=True)
class StepLoss:
    """One training step's objective (what :meth:`ViewModel.training_loss` returns)."""

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
    extra_losses: Mapping[str, Any] = field(default_factory=dict)
    """name -> Float of width 1, added to the loss."""
    aux_rgb: Mapping[str, Any] | None = None
    """name -> Array3f (R,): further colour predictions of the same rays, each supervised by
    the same photometric MSE as ``rgb`` and added to the loss (NeRF's coarse pass)."""

    @property
    def rgb(self):
        return self.composite.rgb


class ParameterShapeError(ValueError):
    """A parameter value whose shape is not the one the model's config builds (a run written by
    another configuration or version of the method)."""

    def __init__(self, key: str, got: tuple, want: tuple) -> None:
        self.key, self.got, self.want = key, tuple(got), tuple(want)
        super().__init__(f"has shape {self.got}, the method's config builds {self.want}")


def check_shapes(current: Mapping[str, Any], values: Mapping[str, Any]) -> None:
    """Raise :class:`ParameterShapeError` for the first of ``values`` not shaped as in ``current``
    (``current``: the model's parameters by key; no doctest here: a second import of this module under
    pytest's importlib mode would duplicate the model classes)."""
    for key, value in values.items():
        if tuple(value.shape) != tuple(current[key].shape):
            raise ParameterShapeError(key, value.shape, current[key].shape)


class Rows(dict):
    """New parameter values (a dict, as :meth:`Model.after_step` returns) whose rows continue old rows: for each key
    in ``sources``, row ``i`` of the new ``(N', ...)`` value continues row ``sources[key][i]`` of the old ``(N, ...)``
    one (-1: a new row). The trainer carries the optimiser's state of those rows (Adam's moments; its step count
    is the parameter's) and starts the new rows' at zero, as when the parameter was first registered."""

    def __init__(self, values: Mapping[str, Any], sources: Mapping[str, Any]) -> None:
        super().__init__(values)
        self.sources = dict(sources)


@dataclass(frozen=True)
class MethodConfig:
    """The fields every method's config has; a method's ``config_type`` subclasses it (and may give ``lr``
    its own default by declaring it again)."""

    lr: float = param(1e-2, lo=0.0, lo_open=True)
    """Adam learning rate (the trainer's schedule scales it)."""


@runtime_checkable
class RendersRays(Protocol):
    """A per-ray model: the trainer's step renders a random batch of training pixels through it."""

    def render_rays(self, o, d, *, u=None, training: bool = False) -> RenderOutput: ...

    def jitter_size(self) -> int: ...


@runtime_checkable
class TrainsOnPixels(Protocol):
    """A model with its own estimator: it writes its step's loss over the trainer's batch of training pixels."""

    def pixel_batch_loss(self, data, batch_rays: int, step: int, rng) -> StepLoss: ...


@runtime_checkable
class TrainsOnViews(Protocol):
    """A whole-view model: it writes its own step's loss."""

    def training_loss(self, data, step: int, rng) -> StepLoss: ...


@runtime_checkable
class FollowsBudget(Protocol):
    """A model whose schedules are fractions of the run's step budget: ``set_budget(steps)`` is called by the
    trainer before the first step (again, with the new budget, when a run is resumed)."""

    def set_budget(self, steps: int) -> None: ...


@runtime_checkable
class ChoosesOptimizer(Protocol):
    """A model that builds its own optimiser: ``optimizer(lr)`` is a ``drjit.opt`` optimiser of learning rate ``lr``
    and no parameters yet (the trainer adds them, and restores its state on resume)."""

    def optimizer(self, lr: float) -> Any: ...


@runtime_checkable
class HasField(Protocol):
    """A model whose learned medium can be queried: ``field()`` is its :class:`~mitsnerf.fields.protocols.Field`
    as trained (a :class:`~mitsnerf.fields.protocols.DensityField` where the density is queryable)."""

    def field(self) -> Field: ...


class Model(ABC):
    """A trainable scene representation (see the module docstring): subclass :class:`RayModel` or
    :class:`ViewModel`, give the class attributes below, and the constructor
    ``__init__(self, config: config_type, scene: SceneInfo, seed: int)``."""

    name: ClassVar[str]
    """The built-in's registry name (a plugin's is its entry point's or variable's)."""
    config_type: ClassVar[type[MethodConfig]]
    """Its settings: a frozen dataclass subclassing :class:`MethodConfig`, every field with a default."""
    description: ClassVar[str]
    """One line saying what the method is, for ``mitsnerf methods``."""
    tiny: ClassVar[Mapping[str, Any]] = MappingProxyType({})
    """Overrides of ``config_type`` making the smallest configuration (the conformance suite's)."""
    knows: ClassVar[tuple[str, ...]] = ()
    """What the method is given besides the training images and their cameras (the tables' ``given`` column):
    e.g. ``("lights", "phase function")`` for a method that reads them from the dataset's spec."""
    rung: ClassVar[str] = "emission-absorption"
    """The physics its renders can represent, which decides the ceiling its row is held against
    (:data:`mitsnerf.oracle.rungs.RUNGS`): ``emission-absorption`` (the oracle), ``single scattering`` (the oracle
    with the remainder on the method's basis: :meth:`rung_basis`), ``full transport`` (the references' agreement
    + 3.01 dB)."""

    def given(self) -> tuple[str, ...]:
        """What this model was given besides the images (the tables' ``given`` column): :attr:`knows`, and what
        its settings add (e.g. ``mitsuba-inverse`` given the albedo)."""
        return self.knows

    def rung_basis(self) -> tuple[int, int]:
        """A single-scattering method's remainder basis ``(L_f, L_z)`` (:mod:`mitsnerf.oracle.rungs`)."""
        raise NotImplementedError(f"{type(self).__name__} is not on the single-scattering rung")

    def __init__(self, config: Any, scene: SceneInfo, seed: int = 0) -> None:
        """The model for one scene, initialised from ``seed`` alone; ``config`` is a ``config_type``."""
        self.config = config

    @abstractmethod
    def parameters(self) -> Mapping[str, Any]:
        """Every trainable value by dotted name: a ``drjit.nn`` module or a plain dict."""

    @abstractmethod
    def set_parameters(self, values: Mapping[str, Any]) -> None:
        """Take new values for (a subset of) the parameters, e.g. from the optimiser."""

    @abstractmethod
    def render_view(self, camera, *, pixel_center: float = 0.5, footprint: int = 1) -> Rendered:
        """A whole camera (without gradients); ``footprint``: K x K rays per pixel (1: its sample point)."""

    @property
    def monte_carlo_renders(self) -> bool:
        """Whether :meth:`render_view` is a Monte Carlo estimate, whose own variance lowers its scores (default:
        a full-transport method's renders are path traced, the others' are quadratures)."""
        return self.rung == "full transport"

    def render_view_independent(self, camera, *, pixel_center: float = 0.5, footprint: int = 1) -> Rendered | None:
        """A second render of ``camera`` with samples independent of :meth:`render_view`'s (another seed), from
        which the evaluation measures the renders' own Monte Carlo variance and scores them without it
        (:mod:`mitsnerf.scoring.variance`); None (the default): no second render, a Monte Carlo method's scores
        are then raw and say so."""
        return None

    def samples_per_ray(self) -> int:
        """Field evaluations per ray (for samples/s figures)."""
        return 0

    def objective_stage(self, step: int) -> int:
        """Which objective step ``step`` (0-based) minimises: a model whose loss changes meaning on the way (a fit
        of another model first, then its own) numbers its stages, and the trainer's divergence check starts afresh
        at each new one; a function of the step alone. Default: 0 throughout."""
        return 0

    def lr_scales(self, step: int) -> Mapping[str, float]:
        """Per-parameter factors on the scheduled learning rate at ``step`` (missing: 1); a
        function of the step alone, so a resumed run schedules exactly as an uninterrupted one."""
        return {}

    def after_step(self, step: int, params: Mapping[str, Any]) -> Mapping[str, Any]:
        """Called after optimiser step ``step`` (0-based) with the optimiser's values; returns new
        values for some parameters (upsampled, clamped), which the trainer writes into the
        optimiser (as :class:`Rows`, rows that continue old rows keep their optimiser state). May update
        the model's non-parameter state (an occupancy grid). Default: none."""
        return {}

    def extra_state(self) -> dict:
        """Non-parameter state to checkpoint (numpy-convertible)."""
        return {}

    def load_extra_state(self, state: Mapping) -> None:  # noqa: B027 (a hook: most models have no extra state)
        """Restore what :meth:`extra_state` returned."""


class RayModel(Model):
    """A per-ray model: it renders batches of rays; whole views are rendered ray by ray."""

    @abstractmethod
    def render_rays(self, o, d, *, u=None, training: bool = False) -> RenderOutput:
        """Render rays ``o + t d`` (Array3f (R,)); ``u``: Float (R * jitter_size()) jitter, or
        None for the deterministic (stratum midpoint) evaluation samples."""

    def jitter_size(self) -> int:
        """Uniform numbers per ray the model's sampler draws in ``u``."""
        return self.samples_per_ray()

    def render_view(self, camera, *, pixel_center: float = 0.5, footprint: int = 1) -> Rendered:
        return render_view(lambda o, d: self.render_rays(o, d).composite, camera,
                           pixel_center=pixel_center, footprint=footprint)


class PixelModel(Model):
    """A model with its own estimator over the trainer's pixel batch, and its own view renderer."""

    @abstractmethod
    def pixel_batch_loss(self, data, batch_rays: int, step: int, rng) -> StepLoss:
        """This step's objective over ``batch_rays`` training pixels it draws with ``rng`` (the step's generator, a
        pure function of seed and step) from ``data``, the trainer's :class:`mitsnerf.train.PixelData`."""


class ViewModel(Model):
    """A whole-view model: its own step's loss, its own view renderer."""

    @abstractmethod
    def training_loss(self, data, step: int, rng) -> StepLoss:
        """This step's objective. ``data``: the trainer's :class:`mitsnerf.train.PixelData`
        (``images`` (V, H, W, 3), ``cameras``); ``rng``: the step's generator, a pure function of
        seed and step, so a resumed run draws the same."""


def num_parameters(params: Mapping[str, Any]) -> int:
    """Total number of scalar parameters."""
    return int(sum(dr.prod(v.shape) if hasattr(v, "shape") and v.shape else dr.width(v) for v in params.values()))


def scene_spec(scene: SceneInfo, method: str, why: str):
    """The dataset's scene spec (:class:`mitsnerf.scene.spec.SceneSpec`, parsed from its manifest) for a method
    that needs what only it holds (``why``: e.g. "its spec gives the lights"); a dataset without one (foreign
    data: NeRF-synthetic, instant-ngp) is a :class:`mitsnerf.errors.DatasetError` in one line naming the method."""
    from mitsnerf.errors import DatasetError
    from mitsnerf.scene.spec import parse_scene

    if not scene.manifest:  # foreign data has no manifest.json: not one to name
        raise DatasetError(None, None, f"{method} needs a dataset made by 'mitsnerf generate' ({why}); this one is "
                                       "foreign data (NeRF-synthetic or instant-ngp), which holds no scene spec")
    spec_data = scene.manifest.get("spec")
    if not spec_data:
        raise DatasetError(None, "manifest.json: spec", f"{method} needs a dataset made by 'mitsnerf generate' "
                                                        f"({why})")
    return parse_scene(spec_data, "manifest.json: spec")


def cover_radiance(field_config, scene: SceneInfo):
    """``field_config`` with ``c_max`` (the largest colour its head can output) raised to
    ``max(1, 1.25 x scene.radiance_max)`` when the training images are brighter than it."""
    if field_config.c_max < scene.radiance_max:
        return replace(field_config, c_max=max(1.0, 1.25 * scene.radiance_max))
    return field_config
