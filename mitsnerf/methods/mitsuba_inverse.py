"""``mitsuba-inverse``: optimise a heterogeneous medium through a differentiable volumetric path tracer.

The physically based route: the scene is the dataset's own (its manifest's spec through
:func:`mitsnerf.scene.to_mitsuba.scene_dict`: the same lights, the medium box, phase function) with the medium's
grids replaced by the unknowns, and each step minimises

    L = mean over pixels and channels of |I_p(tau, albedo) - I*_p|^q  (q = 2, or 1: ``loss``)  (+ priors)

with Adam (UniformAdam by default: ``optimizer``) on ``sigma_t`` and, unless ``optimize_albedo = false``,
``albedo`` (TensorXf (R, R, R, 3)).

**The step** (``batch = "rays"``, the default): the trainer's ``batch_rays`` pixels drawn uniformly over every
training view, each traced by ``spp_primal_factor x spp`` paths for the image the loss compares and by ``spp``
*other* paths (their own seed) for the gradient (:func:`mitsnerf.render.path_batch.render_pixels`); every path
through its own point of its pixel (the box-filtered film's footprint). ``batch = "views"``: ``views_per_step``
whole views through Mitsuba's film (``mi.render``, with the same two spp and seeds), one view's worth of rays
each. ``batch = "sensor"``: every training view at ``1 / sensor_scale`` of its width and height in one render of
Mitsuba's ``batch`` sensor (the route of Nicolet et al. 2023), against the training images box-averaged to that
size (a coarse pixel of the box-filtered film is the mean of the fine pixels it covers).

**Units: optical depth per box side.** The ``sigma_t`` grid holds ``tau = sigma_t * side`` (TensorXf (R, R, R, C),
``C`` = 1, or 3 for a chromatic extinction; the medium's ``scale`` is ``1 / side``), so every setting in its units
(``init_depth``, ``lr``, ``depth_max``, ``majorant_depth``, ``majorant_floor``) means the same in a box of any
size: a bench config states nothing about the box. ``field()`` gives ``sigma_t`` in world units (``tau / side``).

**The gradient** (``estimator``): ``"drt"`` (default) renders through ``mitsnerf_drt``
(:mod:`mitsnerf.render.drt`): differential ratio tracking for the extinction's in-scattering gradient, a
coarse majorant grid (``majorant_cell`` voxels per cell; ``majorant_floor`` keeps a rate where the density is 0,
so that it can grow there); ``"free_flight"``: the same tracer with the in-scattering gradient at the path's own
collisions; ``"prbvolpath"``: Mitsuba 3.9's ``prbvolpath`` (differentiable delta tracking under one global
majorant, the grid's maximum or ``majorant_depth``). The free-flight gradients are biased where the density is 0
(``mitsnerf check``'s ``drt_gradient`` case measures it). A chromatic extinction (``density_channels = 3``, or the
dataset's spec chromatic and ``density_channels = 0``): Mitsuba's RGB variants carry the three channels on every
path; ``mitsnerf_drt`` tracks under the largest channel's majorant and each channel's extinction gets its
gradient from that channel's estimates, while ``prbvolpath`` samples one channel per path for its distances.

**Schedules, as fractions of the step budget** (the trainer tells the model its budget,
:class:`mitsnerf.methods.base.FollowsBudget`): the grids start at ``resolutions[0]`` and are resampled
(trilinear, ``dr.resample``) to ``resolutions[l + 1]`` after step ``round(upsample_at[l] x steps)``; the
optimiser's state for them restarts then and the learning rate is multiplied by ``upsample_lr_factor`` per
upsampling so far, and by ``lr_decay`` at each of ``lr_decay_at``. After every step ``sigma_t`` is clamped to
``[0, depth_max]`` (and ``majorant_depth``), ``albedo`` to ``[0, 1]``.

**Starts.** ``init_depth`` (a constant), ``init_from`` (a directory ``mitsnerf export`` wrote, a run holding one in
``export/``, or a dataset: its true grids, the "truth start"; the grids then start at their final resolution),
``emissive_steps`` (the first steps fit an emission-absorption model whose extinction the path tracer then takes
over, :mod:`mitsnerf.methods.inverse_start`) and ``albedo_first`` (path-traced steps that fit the albedo alone).
``optimize_albedo = false``: the albedo is given, the spec's own (the tables' ``given`` column then says so).

**The haze and the priors** (docs/notes/mitsuba-inverse.md, "mitsuba-inverse: removing the haze", measures each):
under a nearly uniform environment a scattering haze of the right albedo is almost
invisible, so a constant start leaves one. ``carve``: the training views' emptiness mask
(:mod:`mitsnerf.math.carve`, built from ``SceneInfo.train_views`` when the model is): a training pixel whose value
is the environment seen straight through says the medium is empty along its ray, so every voxel its centre ray
crosses is held at 0 (and the majorant grid gets no floor there); ``l1``: ``l1 * mean(tau)``; ``tv_sigma``,
``tv_albedo``: total variation, the mean squared difference of neighbouring voxels that are both inside the mask.

What it knows that the emission-absorption methods do not: the dataset's spec gives it the lights, the phase
function, the medium's box and the path length, so it fits only the extinction and the albedo.

Not supported: foreign datasets (no manifest spec: the lights are unknown), pixel centres other than Mitsuba's
``+0.5``. Evaluation renders whole cameras through Mitsuba's film (box-filtered pixels) at ``eval_spp``; the
opacity and depth maps come from emission-absorption quadrature of the current extinction over the same footprint.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np

from mitsnerf.config import Since, check_fields, param
from mitsnerf.errors import DatasetError, SpecError
from mitsnerf.fields.grid import GridField
from mitsnerf.math.carve import carve_levels
from mitsnerf.methods.base import MethodConfig, PixelModel, SceneInfo, StepLoss, scene_spec
from mitsnerf.methods.inverse_start import masked_tv, resampled_start, tv_pairs
from mitsnerf.methods.optim import QuantileAdam
from mitsnerf.render.camera import Rendered, render_view
from mitsnerf.render.path_batch import PathBatch, render_pixels
from mitsnerf.render.volume import render_rays
from mitsnerf.scene.to_mitsuba import volume_grids

SIGMA_T_SUFFIX = "interior_medium.sigma_t.data"
ALBEDO_SUFFIX = "interior_medium.albedo.data"
EVAL_SEED = 0x5EED
ESTIMATORS = ("drt", "free_flight", "prbvolpath")


def fraction_steps(fractions, budget: int) -> tuple[int, ...]:
    """The steps after which a schedule given as fractions of the step budget acts: ``max(1, round(f x budget))``.

    >>> fraction_steps((0.04, 0.16, 0.36, 0.64), 2000)
    (80, 320, 720, 1280)
    >>> fraction_steps((0.04, 0.16), 10)          # a tiny budget: two upsamplings after step 1, one after step 2
    (1, 2)
    """
    return tuple(max(1, round(f * budget)) for f in fractions)


#: Adam's variants (``optimizer``).
OPTIMIZERS = ("adam", "sparse", "uniform", "amsgrad", "quantile")

#: Runs saved before the ray batches trained one whole view per step, their schedules in steps: none of today's
#: settings reproduces them.
RAY_BATCHES = Since("0.1.0+a387962", refuse="it trained one whole view per step with its schedules in steps "
                                            "(upsample_at); retrain it")


@dataclass(frozen=True)
class MitsubaInverseConfig(MethodConfig):
    """Configuration of the ``mitsuba-inverse`` method (extinctions in optical depth per box side)."""

    resolutions: tuple[int, ...] = param((4, 8, 16, 32, 64), lo=2, hi=512)
    """Grid resolution of each coarse-to-fine stage (one or more)."""
    upsample_at: tuple[float, ...] = param((0.04, 0.16, 0.36, 0.64), lo=0.0, hi=1.0, lo_open=True, hi_open=True)
    """Fractions of the step budget (increasing) after which the grids are resampled to the next resolution."""
    lr_decay_at: tuple[float, ...] = param((0.75, 0.85, 0.95), lo=0.0, hi=1.0, lo_open=True, hi_open=True,
                                          since=RAY_BATCHES)
    """Fractions of the step budget at which the learning rate is multiplied by ``lr_decay``."""
    lr_decay: float = param(0.5, lo=0.0, hi=1.0, lo_open=True, since=RAY_BATCHES)
    """The learning rate's factor at each of ``lr_decay_at``."""
    batch: str = param("rays", choices=("rays", "views", "sensor"), since=RAY_BATCHES)
    """A step's pixels: ``rays``, the trainer's ``batch_rays`` pixels drawn over every training view; ``views``,
    ``views_per_step`` whole training views; ``sensor``, every training view at ``1 / sensor_scale`` of its size in
    one render of Mitsuba's ``batch`` sensor."""
    loss: str = param("l2", choices=("l2", "l1"), since=RAY_BATCHES)
    """The image term: mean squared (``l2``) or absolute (``l1``) error over pixels and channels."""
    estimator: str = param("drt", choices=ESTIMATORS)
    """The gradient: ``drt`` (differential ratio tracking, majorant grid), ``free_flight`` (the same tracer, the
    in-scattering gradient at the path's collisions), ``prbvolpath`` (Mitsuba's, one global majorant)."""
    density_channels: int = param(0, choices=(0, 1, 3))
    """Extinction channels: 1 grey, 3 one per colour (chromatic), 0 as the dataset's spec."""
    init_depth: float = param(10.0, lo=0.0)
    """Initial constant extinction as the optical depth across the box side (at most ``depth_max``)."""
    init_from: str = param("")
    """The start instead of ``init_depth``: a directory written by ``mitsnerf export`` (or a run holding one in
    ``export/``), its density resampled to the grid; a dataset, its true grids (extinction and albedo); or
    ``truth``, the true grids of the dataset trained on (the "truth start": how far a fit of these views drifts
    from the truth) ("": none). The grids then start at the last of ``resolutions``: a start that has its
    structure is not blurred to the first (the recipe's starts from an emission-absorption fit do the same). In a
    bench config, ``"@LABEL"`` starts from the run of the config's row LABEL on the same scene and seed (e.g.
    ``"@ngp"``: the tables' "(ngp start)" row; no fit is the best start on every scene: docs/notes/mitsuba-inverse.md,
    "Starts from every emission-absorption fit, and from scatter's")."""
    emissive_steps: int = param(0, lo=0)
    """Steps of the emissive start (emission-absorption fit of the extinction and an emission grid) before the
    path tracer takes over (0: none)."""
    emissive_rays: int = param(4096, lo=1, hi=1 << 22)
    """Training pixels per step of the emissive start (at most a training step's ``batch_rays``)."""
    init_albedo: float = param(0.6, lo=0.0, hi=1.0)
    """Initial constant albedo (when learned)."""
    albedo_first: int = param(0, lo=0)
    """Path-traced steps (after the emissive start) in which the albedo alone is fitted, the start's extinction
    held: a start too dark for its albedo is otherwise matched by thinning the medium, mass the images do not
    give back."""
    albedo_resolution: int = param(16, lo=1, hi=512, since=RAY_BATCHES)
    """The albedo grid's finest resolution: it follows ``resolutions`` up to this (a coarser albedo than extinction:
    each of its voxels gathers the gradient of more paths; docs/notes/mitsuba-inverse.md, "The choices, at 300 and
    400 steps on the default cloud")."""
    optimize_albedo: bool = param(True)
    """Learn the albedo grid; false: the albedo is given, the dataset spec's own (resampled to the grid)."""
    lr: float = param(0.5, lo=0.0, lo_open=True)
    """Adam learning rate of the extinction (optical depth per box side, per step)."""
    optimizer: str = param("uniform", choices=OPTIMIZERS, since=("0.1.0+40f90c0", "adam"))
    """Adam's variant: ``uniform`` (the default), every voxel's step normalised by the largest second moment of its
    grid (UniformAdam, Nicolet et al. 2021), so that a voxel moves in proportion to its gradient and one whose
    gradient is only noise barely moves (plain Adam steps it by about the learning rate, and the clamp at 0 turns
    that walk into haze: docs/notes/mitsuba-inverse.md, "The optimiser's noise, removed"); ``adam``; ``sparse``, a
    voxel that no path's gradient reached in a step keeps its value and its moments (Dr.Jit's ``mask_updates``, as
    PyTorch's SparseAdam); ``amsgrad``, by the largest second moment each voxel has had; ``quantile``, by the larger
    of its own and ``moment_quantile`` of the grid's (between ``adam`` and ``uniform``)."""
    moment_quantile: float = param(0.99, lo=0.0, hi=1.0)
    """``optimizer = "quantile"``: each voxel's step normalised by the larger of its own second moment and this
    quantile of its grid's nonzero ones (:class:`mitsnerf.methods.optim.QuantileAdam`; 1: ``uniform``)."""
    beta_1: float = param(0.9, lo=0.0, hi=1.0, hi_open=True)
    """Adam's first-moment decay (the steps' gradients averaged over about ``1 / (1 - beta_1)`` steps)."""
    albedo_lr_factor: float = param(0.04, lo=0.0, lo_open=True)
    """The albedo's (and the emissive start's emission's) learning rate relative to the extinction's."""
    upsample_lr_factor: float = param(1.0, lo=0.0, lo_open=True, since=("0.1.0+7377ecc", 0.5))
    """Learning-rate factor applied once per upsampling (1: the recipe's; 0.5 cost 2.8 dB at 300 steps on the
    default cloud, docs/notes/mitsuba-inverse.md, "The choices, at 300 and 400 steps on the default
    cloud")."""
    depth_max: float = param(200.0, lo=0.0, lo_open=True)
    """Clamp of the extinction after each step (optical depth per box side)."""
    majorant_depth: float = param(0.0, lo=0.0)
    """``prbvolpath`` only: a fixed delta-tracking majorant (optical depth per side; also the clamp when below
    ``depth_max``); 0: the grid's maximum after each update."""
    majorant_cell: int = param(4, lo=1, hi=64)
    """``drt``, ``free_flight``: voxels per majorant cell along each axis."""
    majorant_floor: float = param(2.0, lo=0.0)
    """``drt``, ``free_flight``: the least majorant (optical depth per side) outside the emptiness mask, so that
    the gradient reaches voxels whose density is 0."""
    spp: int = param(4, lo=1, hi=4096)
    """Paths per pixel of the gradient (the adjoint pass)."""
    spp_primal_factor: int = param(4, lo=1, hi=1024, since=RAY_BATCHES)
    """The image the loss compares is rendered by this many times ``spp`` paths per pixel, independent of the
    gradient's."""
    views_per_step: int = param(1, lo=1, hi=64)
    """``batch = "views"``: training views rendered per step (drawn at random, with replacement); the image term
    is their mean. At most the training views the data has (:func:`check_batch`)."""
    sensor_scale: int = param(8, lo=1, hi=64)
    """``batch = "sensor"``: each training view is rendered at ``width / sensor_scale`` x ``height / sensor_scale``
    pixels (both must divide: :func:`check_batch`), its target the training image averaged over
    ``sensor_scale^2`` pixels. At 8 a 40-view 64 x 64 dataset gives 2560 pixels a step."""
    l1: float = param(0.0, lo=0.0)
    """Weight of the sparsity prior ``l1 * mean over voxels of tau`` (0: none)."""
    tv_sigma: float = param(0.0, lo=0.0)
    """Weight of the extinction's total variation inside the emptiness mask (mean squared difference of
    neighbouring kept voxels, in optical depth per side; 0: none)."""
    tv_albedo: float = param(0.0, lo=0.0)
    """Weight of the albedo's total variation inside the emptiness mask (0: none)."""
    carve: bool = param(True)
    """Emptiness mask: the extinction is held at 0 in every voxel that a training pixel's centre ray crosses
    when that pixel shows the environment unattenuated (``max over channels |image - background(d)| <=
    carve_tol``), at every resolution (needs the training views, ``SceneInfo.train_views``)."""
    carve_tol: float = param(1e-4, lo=0.0)
    """Largest ``|image - background|`` (linear radiance) of a pixel that counts as unattenuated."""
    max_depth: int = param(0, lo=-1)
    """Path length: 0 takes the dataset's ``render.max_depth`` (-1: unlimited)."""
    eval_spp: int = param(2048, lo=1)
    """Samples per pixel of evaluation renders (their Monte Carlo noise lowers the PSNR: at 128 spp the true
    medium scores about 35 dB on the default cloud's medium pixels, at 2048 about 44)."""

    def __post_init__(self) -> None:
        check_fields(self)
        if not self.resolutions:
            raise ValueError("resolutions: must be one or more sizes, got []")
        if len(self.upsample_at) != len(self.resolutions) - 1:
            raise ValueError(f"upsample_at: needs {len(self.resolutions) - 1} fractions of the budget (one per later "
                             f"resolution), got {list(self.upsample_at)}")
        for name in ("upsample_at", "lr_decay_at"):
            v = getattr(self, name)
            if any(b <= a for a, b in zip(v, v[1:])):
                raise ValueError(f"{name}: must be increasing, got {list(v)}")
        if self.majorant_depth and self.estimator != "prbvolpath":
            raise ValueError(f"majorant_depth: fixes prbvolpath's one majorant; estimator {self.estimator!r} uses a "
                             "majorant grid (majorant_cell, majorant_floor)")
        if self.albedo_first and not self.optimize_albedo:
            raise ValueError("albedo_first: fits the albedo alone, but optimize_albedo is false")
        if self.init_depth > self.depth_clamp:
            raise ValueError(f"init_depth: must be <= {'majorant_depth' if self.majorant_depth else 'depth_max'} "
                             f"({self.depth_clamp:g}), got {self.init_depth:g}")

    @property
    def depth_clamp(self) -> float:
        """The largest optical depth per side kept after a step: ``depth_max``, or ``majorant_depth`` if lower."""
        return min(self.depth_max, self.majorant_depth) if self.majorant_depth else self.depth_max


def _resampled(grid: np.ndarray, r: int) -> np.ndarray:
    """A (R', R', R', C) grid resampled trilinearly to (r, r, r, C) (float32)."""
    if grid.shape[0] == r:
        return np.asarray(grid, dtype=np.float32)
    out = dr.resample(mi.TensorXf(np.ascontiguousarray(grid, dtype=np.float32)), (r, r, r, grid.shape[-1]),
                      filter="linear", boundary="nearest")
    return np.asarray(out, dtype=np.float32)


def _rgb_sensor(camera, spp: int):
    from mitsnerf.scene.to_mitsuba import sensor_dict

    d = sensor_dict(camera, spp)
    d["film"]["pixel_format"] = "rgb"
    return mi.load_dict(d)


def batch_sensor(cameras, images, scale: int, spp: int) -> tuple[Any, Any]:
    """Mitsuba's ``batch`` sensor holding every camera at ``1 / scale`` of its width and height (the films side by
    side, in the cameras' order, box-filtered) and its target: the images, each the mean of its ``scale x scale``
    pixel blocks, side by side (TensorXf (H / scale, n W / scale, 3)).

    >>> import numpy as np
    >>> from mitsnerf import env
    >>> from mitsnerf.math.camera import Camera
    >>> _ = env.set_variant()
    >>> cams = [Camera.from_fov(np.eye(4), 4, 2, 60.0), Camera.from_fov(np.eye(4), 4, 2, 60.0)]
    >>> images = [np.full((2, 4, 3), 1.0), np.arange(24.0).reshape(2, 4, 3)]
    >>> sensor, target = batch_sensor(cams, images, 2, 1)
    >>> sensor.film().size(), target.shape
    ([4, 1], (1, 4, 3))
    >>> np.array(target)[0, :, 0].tolist()  # the first view's two blocks, then the second's
    [1.0, 1.0, 7.5, 13.5]
    """
    from mitsnerf.math.camera import Camera
    from mitsnerf.scene.to_mitsuba import sensor_dict

    w, h = cameras[0].width // scale, cameras[0].height // scale
    desc: dict[str, Any] = {"type": "batch", "sampler": {"type": "independent", "sample_count": int(spp)},
                            "film": {"type": "hdrfilm", "width": w * len(cameras), "height": h,
                                     "rfilter": {"type": "box"}, "pixel_format": "rgb"}}
    for i, cam in enumerate(cameras):
        desc[f"view_{i:04d}"] = sensor_dict(Camera.from_fov(cam.c2w, w, h, cam.fov_x_deg), spp)
    blocks = [np.asarray(img, np.float32)[..., :3].reshape(h, scale, w, scale, 3).mean(axis=(1, 3)) for img in images]
    return mi.load_dict(desc), mi.TensorXf(np.ascontiguousarray(np.concatenate(blocks, axis=1)))


def _integrator(config: MitsubaInverseConfig, max_depth: int, side: float) -> dict[str, Any]:
    """The Mitsuba integrator of ``config.estimator`` (the majorant floor in world units)."""
    if config.estimator == "prbvolpath":
        return {"type": "prbvolpath", "max_depth": int(max_depth)}
    from mitsnerf.render.drt import NAME, register

    register()
    return {"type": NAME, "max_depth": int(max_depth), "majorant_cell": config.majorant_cell,
            "majorant_floor": config.majorant_floor / side, "drt": config.estimator == "drt"}


def check_batch(config: MitsubaInverseConfig, scene: SceneInfo) -> None:
    """Refuse a step the training views cannot give, a SpecError naming the field: ``views_per_step`` above the
    number of training views (``batch = "views"``: each is a path-traced render per step, where more views than the
    data has only repeats them); a ``sensor_scale`` that does not divide every view's width and height, or views of
    different sizes (``batch = "sensor"``: one film holds them side by side)."""
    if scene.train_views is None or config.batch == "rays":
        return
    cameras = scene.train_views.cameras
    if config.batch == "views" and config.views_per_step > len(cameras):
        raise SpecError(None, "views_per_step", f"must be at most the dataset's {len(cameras)} training views (each "
                                                f"step path-traces that many renders), got {config.views_per_step}")
    if config.batch == "sensor":
        sizes = sorted({(cam.width, cam.height) for cam in cameras})
        if len(sizes) > 1:
            raise SpecError(None, "batch", f"'sensor' needs training views of one size, the dataset's are {sizes}")
        k, (w, h) = config.sensor_scale, sizes[0]
        if w % k or h % k:
            raise SpecError(None, "sensor_scale", f"must divide the training views' {w} x {h} pixels, got {k}")


def _cube_side(box) -> float:
    """The side of the scene box, a cube (every spec's box is ``world.scale`` times the unit cube)."""
    size = [float(v) for v in box.size]
    if max(size) - min(size) > 1e-6 * max(size):
        raise DatasetError(None, "manifest.json: spec", f"mitsuba-inverse needs a cubic scene box, got sides {size}")
    return size[0]


class MitsubaInverseModel(PixelModel):
    name = "mitsuba-inverse"
    config_type = MitsubaInverseConfig
    description = "extinction/albedo grids through a differentiable path tracer (differential ratio tracking)"
    knows = ("lights", "phase function")
    rung = "full transport"
    tiny = MappingProxyType({"resolutions": [4, 8], "upsample_at": [0.5], "spp": 2, "eval_spp": 4,
                             "emissive_steps": 4, "emissive_rays": 64, "albedo_first": 1, "tv_sigma": 1e-3,
                             "tv_albedo": 1e-3})

    def __init__(self, config: MitsubaInverseConfig, scene: SceneInfo, seed: int = 0) -> None:
        from mitsnerf.scene.to_mitsuba import scene_dict

        check_batch(config, scene)  # before anything is built
        self.spec = scene_spec(scene, self.name, "its spec gives the lights and the medium's placement")
        self.config, self.box = config, scene.box
        self.side = _cube_side(scene.box)
        self.channels = config.density_channels or (3 if self.spec.volume.chromatic else 1)
        self.max_depth = config.max_depth or self.spec.render.max_depth
        self.budget: int | None = None
        self._keep = self._emptiness_masks(scene) if config.carve else None  # resolution -> (R, R, R) bool
        self._true_albedo = None if config.optimize_albedo else volume_grids(self.spec)[1]
        r = config.resolutions[-1 if config.init_from else 0]
        tau, albedo = self._start(r)
        desc = scene_dict(self.spec, tau[..., 0] if self.channels == 1 else tau, albedo)
        desc["integrator"] = _integrator(config, self.max_depth, self.side)
        desc["medium_box"]["interior"]["scale"] = 1.0 / self.side
        if config.majorant_depth:
            desc["medium_box"]["interior"]["sigma_t"]["max_value"] = float(config.majorant_depth)
        self.scene = mi.load_dict(desc)
        self.params = mi.traverse(self.scene)
        self._key_sigma, self._key_albedo = self._find_key(SIGMA_T_SUFFIX), self._find_key(ALBEDO_SUFFIX)
        self.sigma_t = self._carved(mi.TensorXf(self.params[self._key_sigma]))
        self.params[self._key_sigma] = self.sigma_t
        self.params.update()
        self.albedo = mi.TensorXf(self.params[self._key_albedo])
        self.emission = dr.full(mi.TensorXf, 0.5, (r, r, r, 3)) if config.emissive_steps else None
        self._sensors: dict[int, Any] = {}
        self._targets: dict[int, Any] = {}
        self._batch_sensor: tuple[Any, Any] | None = None  # batch = "sensor": (the sensor, its target image)
        self._background = scene.background
        self._pairs: dict[int, tuple] = {}

    def given(self) -> tuple[str, ...]:
        """The lights and the phase function, and the albedo where it is given (``optimize_albedo = false``)."""
        return self.knows + (() if self.config.optimize_albedo else ("albedo",))

    def _emptiness_masks(self, scene: SceneInfo) -> dict[int, np.ndarray]:
        """The training views' emptiness mask at every resolution (``carve = true``), from ``scene.train_views``:
        a coarse voxel is kept where any finer voxel is."""
        views = scene.train_views
        if views is None:
            raise ValueError("carve: needs the training views (SceneInfo.train_views), and none were given: give "
                             "them, or set carve = false")
        return carve_levels(views.images, views.cameras, scene.background, self.box, self.config.resolutions,
                            self.config.carve_tol, views.pixel_center)

    def _start(self, r: int) -> tuple[np.ndarray, np.ndarray]:
        """The initial extinction (R, R, R, C), optical depth per side, and albedo (R, R, R, 3): ``init_from``'s
        (its albedo where it has one, the given albedo where it is given), or ``init_depth`` and ``init_albedo``."""
        c = self.config
        a = self.albedo_res(r)
        tau = np.full((r, r, r, self.channels), c.init_depth, dtype=np.float32)
        albedo = np.full((a, a, a, 3), c.init_albedo, dtype=np.float32)
        if c.init_from:
            start = (*volume_grids(self.spec), self.box) if c.init_from == "truth" else c.init_from
            tau, start_albedo = resampled_start(start, self.box, r, self.channels)
            tau = np.minimum(tau, np.float32(c.depth_clamp))
            albedo = albedo if start_albedo is None else _resampled(start_albedo, a)
        given = self._given_albedo(r)
        return tau, albedo if given is None else given

    def albedo_res(self, r: int) -> int:
        """The albedo grid's resolution beside an extinction grid of ``r``: ``min(r, albedo_resolution)``."""
        return min(r, self.config.albedo_resolution)

    def _given_albedo(self, r: int) -> np.ndarray | None:
        """The spec's albedo at :meth:`albedo_res` of ``r`` where it is given (``optimize_albedo = false``)."""
        return None if self._true_albedo is None else _resampled(self._true_albedo, self.albedo_res(r))

    def _find_key(self, suffix: str) -> str:
        keys = [k for k in self.params.keys() if k.endswith(suffix)]
        if len(keys) != 1:
            raise RuntimeError(f"expected one scene parameter ending in {suffix!r}, found {keys}")
        return keys[0]

    # ------------------------------------------------------------------ parameters

    def parameters(self) -> Mapping[str, Any]:
        params = {"sigma_t": self.sigma_t}
        if self.config.optimize_albedo:
            params["albedo"] = self.albedo
        if self.emission is not None:
            params["emission"] = self.emission
        return params

    def set_parameters(self, values: Mapping[str, Any]) -> None:
        if "sigma_t" in values:
            self.sigma_t = values["sigma_t"]
            self.params[self._key_sigma] = self.sigma_t
            given = self._given_albedo(self.resolution)
            if given is not None and tuple(self.albedo.shape) != given.shape:
                self.albedo = mi.TensorXf(given)
                self.params[self._key_albedo] = self.albedo
        if "albedo" in values:
            self.albedo = values["albedo"]
            self.params[self._key_albedo] = self.albedo
        if "emission" in values:
            self.emission = values["emission"]
        self.params.update()

    @property
    def resolution(self) -> int:
        return int(self.sigma_t.shape[0])

    def optimizer(self, lr: float) -> Any:
        """The optimiser ``optimizer`` names, with ``beta_1`` (the trainer adds the parameters)."""
        c = self.config
        if c.optimizer == "quantile":
            return QuantileAdam(lr, c.moment_quantile, beta_1=c.beta_1)
        return dr.opt.Adam(lr, beta_1=c.beta_1, mask_updates=c.optimizer == "sparse",
                           uniform=c.optimizer == "uniform", amsgrad=c.optimizer == "amsgrad")

    # ------------------------------------------------------------------ schedules

    def set_budget(self, steps: int) -> None:
        """The run's step budget, which the schedules' fractions are of (the trainer calls this first)."""
        self.budget = int(steps)

    def _steps(self, fractions) -> tuple[int, ...]:
        if self.budget is None:
            raise RuntimeError("mitsuba-inverse: its schedules are fractions of the step budget: call "
                               "set_budget(steps) before stepping (the trainer does)")
        return fraction_steps(fractions, self.budget)

    def level(self, step: int) -> int:
        """Upsamplings done before step ``step`` (0-based) starts; with ``init_from``, all of them from the start."""
        if self.config.init_from:
            return len(self.config.resolutions) - 1
        return sum(1 for s in self._steps(self.config.upsample_at) if s <= step)

    def lr_scales(self, step: int) -> Mapping[str, float]:
        c = self.config
        decays = sum(1 for s in self._steps(c.lr_decay_at) if s <= step)
        factor = c.upsample_lr_factor ** self.level(step) * c.lr_decay ** decays
        held = c.emissive_steps <= step < c.emissive_steps + c.albedo_first
        scales = {"sigma_t": 0.0 if held else factor}
        for key in ("albedo", "emission"):
            if key in self.parameters():
                scales[key] = factor * c.albedo_lr_factor
        return scales

    def objective_stage(self, step: int) -> int:
        """0 during the emissive start, 1 once the path tracer has taken over (its loss carries its render noise)."""
        return int(step >= self.config.emissive_steps)

    def after_step(self, step: int, params: Mapping[str, Any]) -> Mapping[str, Any]:
        """The grids resampled to the resolution of the next step's level; the extinction clamped to
        [0, depth_clamp] and carved, the albedo clamped to [0, 1], the emission to >= 0."""
        new = {key: params[key] for key in ("sigma_t", "albedo", "emission") if key in params}
        r = self.config.resolutions[self.level(step + 1)]
        size = {"sigma_t": r, "emission": r, "albedo": self.albedo_res(r)}
        new = {key: v if v.shape[0] == size[key] else
               dr.resample(v, (size[key],) * 3 + (v.shape[-1],), filter="linear", boundary="nearest")
               for key, v in new.items()}
        new["sigma_t"] = self._carved(dr.clip(new["sigma_t"], 0.0, self.config.depth_clamp))
        if "albedo" in new:
            new["albedo"] = dr.clip(new["albedo"], 0.0, 1.0)
        if "emission" in new:
            new["emission"] = dr.maximum(new["emission"], 0.0)
        self.set_parameters(new)
        return new

    # ------------------------------------------------------------------ training

    def samples_per_ray(self) -> int:
        """Paths per pixel of a step: the primal's and the gradient's."""
        return self.config.spp * (self.config.spp_primal_factor + 1)

    def _keep_mask(self, r: int) -> np.ndarray | None:
        return None if self._keep is None else self._keep[r]

    def _carved(self, sigma_t):
        """``sigma_t`` times the emptiness mask of its resolution (itself without one); the path tracer's majorant
        floor then stays inside the mask."""
        r = int(sigma_t.shape[0])
        keep = self._keep_mask(r)
        if keep is None:
            return sigma_t
        if self.config.estimator != "prbvolpath":
            self.scene.integrator().free = keep
        c = int(sigma_t.shape[-1])
        return sigma_t * mi.TensorXf(np.repeat(keep[..., None], c, axis=-1).astype(np.float32))

    def priors(self, sigma_t):
        """``l1 mean(tau) + tv_sigma TV(tau) + tv_albedo TV(albedo)`` (TV over neighbouring voxels inside the mask;
        Float of width 1, differentiable)."""
        c = self.config
        total = mi.Float(0.0)
        if c.l1:
            total += c.l1 * mi.Float(dr.mean(sigma_t.array))
        if c.tv_sigma or c.tv_albedo:
            r = int(sigma_t.shape[0])
            if r not in self._pairs:
                keep = self._keep_mask(r)
                self._pairs[r] = tv_pairs(np.ones((r, r, r), bool) if keep is None else keep)
            if c.tv_sigma:
                total += c.tv_sigma * masked_tv(sigma_t, self._pairs[r], int(sigma_t.shape[-1]))
            if c.tv_albedo and c.optimize_albedo:
                a = int(self.albedo.shape[0])
                if a not in self._pairs:
                    keep = None if self._keep is None else self._keep.get(a)
                    self._pairs[a] = tv_pairs(np.ones((a, a, a), bool) if keep is None else keep)
                total += c.tv_albedo * masked_tv(self.albedo, self._pairs[a], 3)
        return total

    def pixel_batch_loss(self, data, batch_rays: int, step: int, rng) -> StepLoss:
        """The emissive start's loss for its first ``emissive_steps`` steps, then the path tracer's over
        ``batch_rays`` pixels of every view (:meth:`rays_error`), over whole views (:meth:`views_error`) or over
        every view at a coarser size (:meth:`sensor_error`), each plus :meth:`priors`, of the extinction times the
        emptiness mask (``carve``)."""
        if data is None or data.images is None or not data.cameras:
            raise ValueError("mitsuba-inverse trains on views: PixelData.from_views gives them")
        if abs(data.pixel_center - 0.5) > 1e-9:
            raise ValueError(
                f"mitsuba-inverse renders with Mitsuba's pixel centres (+0.5), the data has {data.pixel_center}"
            )
        sigma_t = self._carved(self.sigma_t)
        if step < self.config.emissive_steps:
            term = mse = self.emissive_mse(data, sigma_t, rng)
            rays = self.config.emissive_rays
        else:
            self.params[self._key_sigma] = sigma_t
            self.params.update()
            errors = {"rays": self.rays_error, "views": self.views_error, "sensor": self.sensor_error}
            term, mse, rays = errors[self.config.batch](data, sigma_t, batch_rays, rng)
        c = self.config
        loss = term + self.priors(sigma_t) if (c.l1 or c.tv_sigma or c.tv_albedo) else term
        return StepLoss(loss, dr.detach(mse), rays)

    def emissive_mse(self, data, sigma_t, rng):
        """The emissive start: ``emissive_rays`` random training pixels (jittered in their pixel) rendered by
        emission-absorption quadrature of ``sigma_t / side`` and the emission grid (``2 R`` samples per ray)."""
        o, d, target = data.batch(rng, self.config.emissive_rays, True)
        n = 2 * int(sigma_t.shape[0])
        field = GridField.from_arrays(sigma_t / self.side, self.box, self.emission)
        out = render_rays(field, o, d, n, box=self.box, u=rng.random(mi.Float, self.config.emissive_rays * n),
                          background=self._background)
        return mi.Float(dr.mean(dr.square(out.rgb - target), axis=None))

    def _image_term(self, image, target):
        """``(loss term, mse)`` of an estimate against its target (Float of width 1 each)."""
        diff = image - target
        mse = mi.Float(dr.mean(dr.square(diff), axis=None))
        return (mi.Float(dr.mean(dr.abs(diff), axis=None)) if self.config.loss == "l1" else mse), mse

    def _seeds(self, rng, n: int) -> list[int]:
        """``2 n`` distinct seeds drawn with the step's ``rng`` (a primal's and its gradient's, ``n`` times)."""
        u = np.asarray(rng.random(mi.Float, 2 * n), dtype=np.float64)
        return [int(v * 2**31) * 2 + (k % 2) for k, v in enumerate(u)]

    def rays_error(self, data, sigma_t, batch_rays: int, rng) -> tuple[Any, Any, int]:
        """``batch_rays`` pixels drawn uniformly over every training view, each at ``spp_primal_factor x spp``
        paths for the image and ``spp`` others for the gradient (:func:`~mitsnerf.render.path_batch.render_pixels`):
        ``(loss term, mse, camera rays)``."""
        c = self.config
        index = dr.minimum(mi.UInt32(rng.random(mi.Float, batch_rays) * data.size), data.size - 1)
        seed, seed_grad = self._seeds(rng, 1)
        batch = PathBatch(self.scene, self.scene.integrator(), index, data.pixels.rays)
        image = render_pixels(batch, self._attached(sigma_t), spp=c.spp * c.spp_primal_factor, spp_grad=c.spp,
                              seed=seed, seed_grad=seed_grad)
        term, mse = self._image_term(image, dr.gather(mi.Array3f, data.rgb, index))
        return term, mse, batch_rays

    def _attached(self, sigma_t) -> dict[str, Any]:
        params = {"sigma_t": sigma_t}
        if self.config.optimize_albedo:
            params["albedo"] = self.albedo
        return params

    def views_error(self, data, sigma_t, batch_rays: int, rng) -> tuple[Any, Any, int]:
        """``views_per_step`` random training views through Mitsuba's film, each at ``spp_primal_factor x spp``
        samples per pixel for the image and ``spp`` others for the gradient: their mean ``(loss term, mse,
        camera rays)``."""
        c = self.config
        n_views, v = len(data.cameras), min(c.views_per_step, len(data.cameras))
        u = np.asarray(rng.random(mi.Float, v), dtype=np.float64)
        seeds = self._seeds(rng, v)
        term = mse = None
        rays = 0
        for k in range(v):
            i = min(int(u[k] * n_views), n_views - 1)
            if i not in self._sensors:
                self._sensors[i] = _rgb_sensor(data.cameras[i], c.spp)
                self._targets[i] = mi.TensorXf(np.ascontiguousarray(data.images[i], dtype=np.float32))
            img = mi.render(self.scene, self.params, sensor=self._sensors[i], spp=c.spp * c.spp_primal_factor,
                            spp_grad=c.spp, seed=seeds[2 * k], seed_grad=seeds[2 * k + 1])
            t, m = self._image_term(img.array, self._targets[i].array)
            term, mse = (t, m) if term is None else (term + t, mse + m)
            rays += data.cameras[i].width * data.cameras[i].height
        return term / v, mse / v, rays

    def sensor_error(self, data, sigma_t, batch_rays: int, rng) -> tuple[Any, Any, int]:
        """Every training view at ``1 / sensor_scale`` of its size in one render of a ``batch`` sensor, at
        ``spp_primal_factor x spp`` samples per pixel for the image and ``spp`` others for the gradient, against the
        box-averaged training images: ``(loss term, mse, camera rays)``."""
        c = self.config
        if self._batch_sensor is None:
            self._batch_sensor = batch_sensor(data.cameras, data.images, c.sensor_scale, c.spp)
        sensor, target = self._batch_sensor
        seed, seed_grad = self._seeds(rng, 1)
        img = mi.render(self.scene, self.params, sensor=sensor, spp=c.spp * c.spp_primal_factor, spp_grad=c.spp,
                        seed=seed, seed_grad=seed_grad)
        term, mse = self._image_term(img.array, target.array)
        return term, mse, int(target.shape[0] * target.shape[1])

    # ------------------------------------------------------------------ rendering

    def field(self) -> GridField:
        """The medium as a field: ``sigma_t`` in world units (``tau / side``) and, as its colour, the albedo."""
        return GridField.from_arrays(dr.detach(self.sigma_t) / self.side, self.box, dr.detach(self.albedo))

    def render_view(self, camera, *, pixel_center: float = 0.5, footprint: int = 1) -> Rendered:
        """The path tracer at ``eval_spp`` through Mitsuba's box-filtered film for the colour; opacity and depth
        by quadrature of the extinction with ``max(footprint, 2)`` rays per pixel side."""
        return self._render(camera, EVAL_SEED, pixel_center, footprint)

    def render_view_independent(self, camera, *, pixel_center: float = 0.5, footprint: int = 1) -> Rendered:
        """:meth:`render_view` from another seed: the pair measures the renders' own Monte Carlo variance."""
        return self._render(camera, EVAL_SEED + 1, pixel_center, footprint)

    def _render(self, camera, seed: int, pixel_center: float, footprint: int) -> Rendered:
        if abs(pixel_center - 0.5) > 1e-9:
            raise ValueError(f"mitsuba-inverse renders with Mitsuba's pixel centres (+0.5), asked for {pixel_center}")
        with dr.suspend_grad():
            img = mi.render(self.scene, sensor=_rgb_sensor(camera, self.config.eval_spp),
                            spp=self.config.eval_spp, seed=seed)
            rgb = np.array(img, dtype=np.float32)
            density = GridField.from_arrays(dr.detach(self.sigma_t) / self.side, self.box)
            n = 2 * self.resolution
            quad = render_view(lambda o, d: render_rays(density, o, d, n, box=self.box), camera,
                               pixel_center=pixel_center, footprint=max(footprint, 2))
        return Rendered(rgb, quad.opacity, quad.depth)


#: The method this module declares (:mod:`mitsnerf.methods` registers it as ``mitsuba-inverse``).
METHOD = MitsubaInverseModel
