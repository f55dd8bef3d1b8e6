"""``primitives``: a cloud of anisotropic kernels, each with a density and an SH colour, densified and pruned on
a schedule of steps.

The field is :class:`mitsnerf.fields.primitives.PrimitiveField`: ``sigma(x) = sum_k sigma_k g_k(x)``, each kernel a
Gaussian truncated at ``cutoff`` standard deviations (or, with ``field.kernel = "ellipsoid"``, EVER's
constant-density ellipsoid), the colour at a point the density-weighted mean of the kernels' SH colours (one
density per colour channel with ``field.density_channels = 3``). It renders through
:func:`mitsnerf.render.primitives.render_primitives`: every ray walks the cells of the kernels' list grid and
each kernel adds its exact optical depth over the ray's segment in the cell (the integral of a Gaussian along
a line is an ``erf``, an ellipsoid's a chord), so the transmittance is exact at every cell boundary whatever the
overlap; the gradient is replayed per ray. Being the sum of its kernels, the density is what the density scores
and ``mitsnerf export`` read, and it is the medium the images were rendered from.

Initialisation, from the seed alone: ``count`` kernels at uniform random positions in the box, isotropic with
scale ``init_scale`` times the mean spacing ``(V / count)^(1/3)``, grey 0.5 whatever ``c_max`` is (band 0 of the
SH colour only), their density set so that the box holds ``sigma_init`` on average.

Densification and pruning, every ``densify_every`` steps from ``densify_from`` through ``densify_until``:

- *prune*: a kernel whose largest optical depth along any ray (through its centre along its longest axis,
  ``sigma_k sqrt(2 pi) s_max erf(cutoff / sqrt 2)`` for a Gaussian) is below ``prune_tau``, or whose support has
  left the box, is removed (it changes no pixel by more than ``prune_tau`` of its radiance);
- *densify*: of the others, the ``densify_fraction`` with the largest mean norm of their position's gradient
  over the steps since the last densification (3DGS's criterion, in world space: a kernel the images pull in
  different directions is under-resolving the medium) each become two (``densify_rule``): by default its two
  halves along its longest axis, which keep its mean, covariance and mass (:func:`_halves`), or as 3DGS does,
  two children drawn from it (``sample``);
- never beyond ``max_count`` kernels.

The parameters change shape then; the kernels kept carry their Adam state and the new ones start from zero
moments (:class:`~mitsnerf.methods.base.Rows`), as 3DGS does.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from types import MappingProxyType
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np

from mitsnerf.config import check_fields, param
from mitsnerf.fields.primitives import (
    PARAMETER_COLUMNS,
    CellLists,
    Kernels,
    PrimitiveField,
    PrimitiveFieldConfig,
    kernel_volume,
    largest_line_integral,
)
from mitsnerf.fields.sh import colour_start
from mitsnerf.methods.base import (
    MethodConfig,
    ParameterShapeError,
    RayModel,
    RenderOutput,
    Rows,
    SceneInfo,
    cover_radiance,
)
from mitsnerf.render.primitives import render_primitives

KEYS = tuple(PARAMETER_COLUMNS)
"""The parameters, each (N, columns): mean, log_scale, rotation, density, sh."""


@dataclass(frozen=True)
class PrimitivesMethodConfig(MethodConfig):
    """Configuration of the ``primitives`` method."""

    field: PrimitiveFieldConfig = param(default_factory=PrimitiveFieldConfig)
    """What each kernel holds (SH degree, density channels, truncation) and the cells that list them."""
    count: int = param(2048, lo=1, hi=10**7)
    """Kernels at the start, at uniform random positions in the box."""
    max_count: int = param(20000, lo=1, hi=10**7)
    """Densification stops adding kernels here."""
    init_scale: float = param(0.5, lo=0.0, lo_open=True)
    """Initial scale of every kernel, as a fraction of the mean spacing ``(V / count)^(1/3)``."""
    sigma_init: float = param(0.1, lo=0.0, lo_open=True)
    """Mean density (1/length) of the initial kernels over the box."""
    densify_every: int = param(100, lo=1)
    """Steps between densifications (and prunings)."""
    densify_from: int = param(100, lo=1)
    """First step (counted from 1) after which the kernels are densified and pruned."""
    densify_until: int = param(700, lo=0)
    """Last step (counted from 1) after which they may be (0: never)."""
    densify_fraction: float = param(0.1, lo=0.0, hi=1.0)
    """Share of the kernels split or cloned at each densification: those of largest mean positional gradient."""
    densify_rule: str = param("halve", choices=("halve", "sample"))
    """How a kernel becomes two: ``halve``, two halves along its longest axis that keep its mean, variance and
    mass (the field barely changes); ``sample``, 3DGS's: two children drawn from the kernel's Gaussian, smaller
    and denser where it is larger than ``split_scale`` (split), the same size and half as dense otherwise (clone)."""
    split_scale: float = param(0.01, lo=0.0)
    """``densify_rule = "sample"``: a kernel whose largest scale exceeds this fraction of the box's largest side is
    split (smaller children), a smaller one cloned."""
    prune_tau: float = param(1e-3, lo=0.0)
    """Kernels whose largest optical depth along any ray is below it are removed at each densification."""
    min_transmittance: float = param(1e-4, lo=0.0, hi=1.0, hi_open=True)
    """A ray stops where its transmittance is below it in every channel."""
    lr: float = param(0.1, lo=0.0, lo_open=True)
    """Adam learning rate of the densities (raw, ``sigma = exp(raw)``); the others below."""
    lr_mean: float = param(1e-3, lo=0.0, lo_open=True)
    """Learning rate of the positions, in units of the box's largest side."""
    lr_scale: float = param(5e-3, lo=0.0, lo_open=True)
    """Learning rate of the log scales."""
    lr_rotation: float = param(1e-3, lo=0.0, lo_open=True)
    """Learning rate of the quaternions."""
    lr_sh: float = param(0.1, lo=0.0, lo_open=True)
    """Learning rate of the SH coefficients."""

    def __post_init__(self) -> None:
        check_fields(self)
        if self.max_count < self.count:
            raise ValueError(f"max_count: must be >= count ({self.count}), got {self.max_count}")

    def densifies_after(self, step: int) -> bool:
        """Whether the kernels are densified and pruned after (0-based) ``step``.

        >>> PrimitivesMethodConfig(densify_every=100, densify_from=100, densify_until=300).densifies_after(199)
        True
        >>> [s for s in range(1000) if PrimitivesMethodConfig(densify_until=300).densifies_after(s)]
        [99, 199, 299]
        """
        n = step + 1
        return self.densify_from <= n <= self.densify_until and n % self.densify_every == 0


def initial_kernels(config: PrimitivesMethodConfig, box, seed: int) -> dict[str, np.ndarray]:
    """The starting kernels (module docstring) as float32 arrays by parameter, drawn from ``seed`` alone; their
    colour grey 0.5 at ``config.field.c_max`` (:func:`~mitsnerf.fields.sh.colour_start`).

    >>> from mitsnerf.math.box import UNIT_BOX
    >>> k = initial_kernels(PrimitivesMethodConfig(count=8, sigma_init=0.5), UNIT_BOX, 0)
    >>> k["mean"].shape, k["sh"].shape, float(np.exp(k["log_scale"][0, 0]))  # half the spacing 1/2
    ((8, 3), (8, 12), 0.25)
    >>> round(float(np.sum(np.exp(k["density"][:, 0]) * kernel_volume(k["log_scale"]))), 4)  # the mass 0.5 V
    0.5
    """
    rng = np.random.default_rng([int(seed), 0x5EED])
    n, cfg = config.count, config.field
    lo, size = np.asarray(box.lo), np.asarray(box.size)
    volume = float(np.prod(size))
    scale = config.init_scale * (volume / n) ** (1.0 / 3.0)
    log_scale = np.full((n, 3), math.log(scale))
    sigma = config.sigma_init * volume / (n * kernel_volume(log_scale[:1], cfg.kernel)[0])
    out = {"mean": lo + rng.random((n, 3)) * size, "log_scale": log_scale,
           "rotation": np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)),
           "density": np.full((n, cfg.density_channels), math.log(sigma)),
           "sh": np.tile(colour_start(cfg.sh_degree, cfg.c_max), (n, 1))}
    return {k: v.astype(np.float32) for k, v in out.items()}


def largest_optical_depth(density: np.ndarray, log_scale: np.ndarray, config: PrimitiveFieldConfig) -> np.ndarray:
    """Each kernel's largest optical depth along any ray (N,), through its centre along its longest axis:
    ``max_c exp(density_c)`` times :func:`~mitsnerf.fields.primitives.largest_line_integral`.

    >>> round(float(largest_optical_depth(np.zeros((1, 1)), np.zeros((1, 3)), PrimitiveFieldConfig())[0]), 4)
    2.4999
    """
    return np.exp(density.max(axis=1)) * largest_line_integral(log_scale.max(axis=1), config)


def _rotation_matrices(q: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotations of quaternions ``(x, y, z, w)`` (normalised here), Dr.Jit's convention."""
    q = q / np.maximum(np.linalg.norm(q, axis=1, keepdims=True), 1e-30)
    x, y, z, w = q.T
    return np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
                     2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
                     2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=1).reshape(-1, 3, 3)


def prune_mask(params: Mapping[str, np.ndarray], config: PrimitivesMethodConfig, box) -> np.ndarray:
    """The kernels kept (Bool (N,)): optical depth at least ``prune_tau`` and some of the shell inside the box."""
    reach = config.field.radius * np.exp(params["log_scale"].max(axis=1))[:, None]
    inside = np.all((params["mean"] + reach > np.asarray(box.lo)) & (params["mean"] - reach < np.asarray(box.hi)), 1)
    thick = largest_optical_depth(params["density"], params["log_scale"], config.field) >= config.prune_tau
    return inside & thick & np.all(np.isfinite(params["mean"]), axis=1)


def densify(params: Mapping[str, np.ndarray], score: np.ndarray, config: PrimitivesMethodConfig, box,
            rng: np.random.Generator) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Prune, then split or clone the kernels of largest ``score`` (module docstring): ``(new arrays, sources)``,
    ``sources[i]`` the old kernel that new kernel ``i`` is (-1: a child, new).

    Survivors keep their order; the chosen kernels' two children follow them.

    >>> from mitsnerf.math.box import UNIT_BOX
    >>> cfg = PrimitivesMethodConfig(count=4, densify_fraction=0.5)
    >>> k = initial_kernels(cfg, UNIT_BOX, 0)
    >>> new, sources = densify(k, np.array([0.0, 3.0, 1.0, 2.0]), cfg, UNIT_BOX, np.random.default_rng(0))
    >>> sources.tolist(), len(new["mean"])  # kernels 1 and 3 halved
    ([0, 2, -1, -1, -1, -1], 6)
    """
    keep = prune_mask(params, config, box)
    kept = {key: v[keep] for key, v in params.items()}
    score = np.where(np.isfinite(score[keep]), score[keep], 0.0)
    n = len(score)
    chosen_n = min(int(config.densify_fraction * n), max(config.max_count - n, 0), int(np.sum(score > 0)))
    chosen = np.argsort(-score, kind="stable")[:chosen_n]
    rest = np.setdiff1d(np.arange(n), chosen)
    parents = {key: v[chosen] for key, v in kept.items()}
    children = _halves(parents) if config.densify_rule == "halve" else \
        [_child(parents, config, box, rng) for _ in range(2)]
    new = {key: np.concatenate([kept[key][rest]] + [c[key] for c in children]).astype(np.float32) for key in KEYS}
    return new, np.concatenate([np.flatnonzero(keep)[rest], np.full(2 * len(chosen), -1)])


def _halves(parent: Mapping[str, np.ndarray]) -> list[dict[str, np.ndarray]]:
    """The two halves of each parent along its longest axis ``a`` (scale ``s``): centres ``mu +- s/2`` along it,
    scale ``sqrt(3)/2 s`` there (the pair's mean and variance are the parent's), each ``1/sqrt(3)`` as dense (half
    the mass each)."""
    scale = np.exp(parent["log_scale"])
    a = np.argmax(scale, axis=1)
    rows = np.arange(len(a))
    axis = _rotation_matrices(parent["rotation"])[rows, :, a]
    offset = 0.5 * scale[rows, a][:, None] * axis
    log_scale = parent["log_scale"].copy()
    log_scale[rows, a] += math.log(math.sqrt(3.0) / 2.0)
    density = parent["density"] - math.log(math.sqrt(3.0))
    return [{"mean": parent["mean"] + sign * offset, "log_scale": log_scale, "rotation": parent["rotation"],
             "density": density, "sh": parent["sh"]} for sign in (1.0, -1.0)]


def _child(parent: Mapping[str, np.ndarray], config: PrimitivesMethodConfig, box,
           rng: np.random.Generator) -> dict[str, np.ndarray]:
    """One child of each parent: drawn from the parent's Gaussian; smaller and denser where the parent is split."""
    scale = np.exp(parent["log_scale"])
    offset = np.einsum("nij,nj->ni", _rotation_matrices(parent["rotation"]), scale * rng.standard_normal(scale.shape))
    split = scale.max(axis=1) > config.split_scale * max(box.size)
    shrink = np.where(split, math.log(1.6), 0.0)
    gain = np.where(split, math.log(1.6**3 / 2.0), math.log(0.5))
    return {"mean": parent["mean"] + offset, "log_scale": parent["log_scale"] - shrink[:, None],
            "rotation": parent["rotation"], "density": parent["density"] + gain[:, None], "sh": parent["sh"]}


def _check_parameters(values: Mapping[str, Any], config: PrimitiveFieldConfig) -> None:
    """Every parameter a tensor ``(N, columns)`` of one ``N >= 1`` (else a ParameterShapeError)."""
    n = int(values["mean"].shape[0]) if len(values["mean"].shape) == 2 else 0
    for key in KEYS:
        want = (max(n, 1), config.columns(key))
        if tuple(values[key].shape) != want:
            raise ParameterShapeError(key, tuple(values[key].shape), want)


class PrimitivesModel(RayModel):
    name = "primitives"
    config_type = PrimitivesMethodConfig
    description = "anisotropic Gaussian kernels, closed-form optical depth, densified and pruned"
    tiny = MappingProxyType({"count": 48, "max_count": 96, "field": {"cells": 4}, "densify_every": 2,
                             "densify_from": 2, "densify_until": 5, "densify_fraction": 0.25})

    def __init__(self, config: PrimitivesMethodConfig, scene: SceneInfo, seed: int = 0) -> None:
        self.config = config
        self.field_config = field = cover_radiance(config.field, scene)
        self.scene, self.seed = scene, seed
        start = initial_kernels(replace(config, field=field), scene.box, seed)
        self.params = {k: mi.TensorXf(v) for k, v in start.items()}
        self._lists: CellLists | None = None
        self._stats: dict = {}
        self._reset_scores()
        self.visits, self.visited_rays = 0.0, 0

    def parameters(self) -> Mapping[str, Any]:
        return dict(self.params)

    @property
    def count(self) -> int:
        """Kernels now."""
        return int(self.params["mean"].shape[0])

    def set_parameters(self, values: Mapping[str, Any]) -> None:
        """New values for (some of) the parameters, all of one kernel count ``N`` (any: densification changes it),
        each ``(N, columns)`` (else a ParameterShapeError)."""
        new = {**self.params, **{k: values[k] for k in KEYS if k in values}}
        _check_parameters(new, self.field_config)
        self.params = new
        self._lists = None

    def _kernels(self) -> Kernels:
        return Kernels(self.field_config, self.params)

    def lists(self) -> CellLists:
        """The kernels' cell lists, rebuilt after the parameters changed."""
        if self._lists is None:
            with dr.suspend_grad():
                self._lists = CellLists.build(Kernels(self.field_config, self.params), self.scene.box, mi.UInt32)
        return self._lists

    def field(self) -> PrimitiveField:
        """The kernels as a field (without gradients): its density is their sum."""
        with dr.suspend_grad():
            return PrimitiveField(Kernels(self.field_config, self.params).detached(), self.scene.box, self.lists())

    def samples_per_ray(self) -> int:
        """Kernel evaluations per training ray in the march (the mean over the steps so far; a diagnostic)."""
        return int(round(self.visits / self.visited_rays)) if self.visited_rays else 0

    def jitter_size(self) -> int:
        return 0

    def lr_scales(self, step: int) -> Mapping[str, float]:
        c = self.config
        return {"mean": c.lr_mean * max(self.scene.box.size) / c.lr, "log_scale": c.lr_scale / c.lr,
                "rotation": c.lr_rotation / c.lr, "sh": c.lr_sh / c.lr}

    def render_rays(self, o, d, *, u=None, training: bool = False) -> RenderOutput:
        comp = render_primitives(self._kernels(), self.lists(), o, d, box=self.scene.box,
                                 background=self.scene.background, min_transmittance=self.config.min_transmittance,
                                 stats=self._stats if training else None)
        if training:
            self.visits += float(dr.sum(mi.Float(self._stats["visits"]))[0])
            self.visited_rays += dr.width(o)
        return RenderOutput(comp)

    def _reset_scores(self) -> None:
        n = self.count
        self.grad_sum, self.grad_hits = dr.zeros(mi.Float, n), dr.zeros(mi.Float, n)

    def _accumulate(self) -> None:
        """Add this step's positional gradient norms (from the backward pass's geometry gradient)."""
        grad = self._stats.pop("geometry_grad", None)
        if grad is None or dr.width(grad) != 12 * dr.width(self.grad_sum):
            return
        index = dr.arange(mi.UInt32, dr.width(self.grad_sum)) * 12
        g = mi.Array3f(*(dr.gather(mi.Float, grad, index + j) for j in range(3)))
        norm = dr.norm(g)
        self.grad_sum, self.grad_hits = self.grad_sum + norm, self.grad_hits + dr.select(norm > 0, 1.0, 0.0)
        dr.schedule(self.grad_sum, self.grad_hits)

    def after_step(self, step: int, params: Mapping[str, Any]) -> Mapping[str, Any]:
        """Accumulate the positional gradients; on the schedule, prune and densify (new parameters of a new count)."""
        self._accumulate()
        if not self.config.densifies_after(step):
            return {}
        host = {k: np.asarray(params[k].numpy(), np.float64).reshape(self.params[k].shape) for k in KEYS}
        score = np.asarray(self.grad_sum.numpy()) / np.maximum(np.asarray(self.grad_hits.numpy()), 1.0)
        new, sources = densify(host, score, self.config, self.scene.box,
                               np.random.default_rng([int(self.seed), int(step)]))
        if len(new["mean"]) == 0:
            return {}
        values = {k: mi.TensorXf(v) for k, v in new.items()}
        self.set_parameters(values)
        self._reset_scores()
        return Rows(values, {k: sources for k in KEYS})

    def extra_state(self) -> dict:
        return {"densify.grad_sum": np.asarray(self.grad_sum.numpy()),
                "densify.grad_hits": np.asarray(self.grad_hits.numpy())}

    def load_extra_state(self, state: Mapping) -> None:
        if "densify.grad_sum" in state:
            self.grad_sum = mi.Float(np.asarray(state["densify.grad_sum"], np.float32))
            self.grad_hits = mi.Float(np.asarray(state["densify.grad_hits"], np.float32))


#: The method this module declares (:mod:`mitsnerf.methods` registers it as ``primitives``).
METHOD = PrimitivesModel
