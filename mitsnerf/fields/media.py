"""What a learned participating medium holds at a point: its extinction, its albedo, and ``K`` coefficients per colour
of a remainder (:mod:`mitsnerf.fields.scatter`), on dense grids or on a hash grid with two small MLPs.

A medium answers ``lookup(x) -> (sigma, albedo, rest)`` (``sigma`` a Float, or an Array3f with one extinction per
colour; ``albedo`` an Array3f in [0, 1]; ``rest`` a list of ``3 K`` Floats, coefficient ``k`` of colour ``c`` at
``3 k + c``), ``density(x)``, and ``shadow_density(resolution)``: a density cheap enough to march towards the lights
from every cell of a cache (the grid itself, or the hash medium's density sampled on a grid), differentiable.

- :class:`GridMedium`, three textures looked up trilinearly (``voxel``'s lookup) then activated::

      sigma = sigma_scale softplus(s)   (or relu)      albedo = sigmoid(q)   (or clip to [0, 1])      rest = k

- :class:`HashMedium`, instant-ngp's encoding (:class:`drjit.nn.HashGridEncoding` of the unit position) and two
  MLPs (:mod:`mitsnerf.fields.mlp`, point-major, ReLU)::

      [s, f]         = MLP_sigma(h(x))                 sigma = exp(min(s, 15))   (as the ngp field)
      [q, k]         = MLP_c(f)                        albedo = sigmoid(q), rest = k

  The colour MLP's output bias starts at ``logit(albedo_init)`` and ``rest_init``, so the medium's colour starts
  near the light around it whatever the network's weights. Its shadow density is its density sampled at the
  centres of an ``R^3`` grid (in the step's AD graph) and looked up trilinearly: what the transmittance cache
  marches through, ``R^3`` network evaluations instead of one per march sample.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import drjit as dr
import numpy as np

from mitsnerf.config import check_fields, param
from mitsnerf.fields.grid import extinction
from mitsnerf.fields.hashgrid import HashGridConfig
from mitsnerf.fields.mlp import column, dense_apply, dense_init, rows_tensor
from mitsnerf.math.activations import sigmoid, softplus
from mitsnerf.math.box import Box

SIGMA_RAW_MAX = 15.0
"""The hash medium's largest density pre-activation (``exp(15)``), as the ngp field's."""


def texture(tensor):
    """A trilinear, clamped, differentiable ``Texture3f`` of a (R, R, R, C) tensor (``use_accel=False``)."""
    import mitsuba as mi

    return mi.Texture3f(tensor, use_accel=False, filter_mode=dr.FilterMode.Linear, wrap_mode=dr.WrapMode.Clamp)


def cell_centres(box: Box, resolution: int, Array3f):
    """World positions (Array3f (R^3,)) of an ``R^3`` grid's voxel centres over ``box``, x fastest (``[z, y, x]``
    order, as a tensor (R, R, R, C) is laid out)."""
    Float = type(Array3f().x)
    UInt32 = dr.uint32_array_t(Float)
    r = int(resolution)
    idx = dr.arange(UInt32, r**3)
    i, j, k = idx % r, (idx // r) % r, idx // (r * r)
    return box.from_unit(Array3f((Float(i) + 0.5) / r, (Float(j) + 0.5) / r, (Float(k) + 0.5) / r))


def grid_of(values, resolution: int, TensorXf):
    """A (R, R, R, C) tensor of per-cell values (a Float, or an Array3f: C = 3) in :func:`cell_centres`' order."""
    import mitsuba as mi

    channels = [values] if not isinstance(values, mi.Array3f) else [values.x, values.y, values.z]
    r = int(resolution)
    return TensorXf(dr.ravel(mi.ArrayXf(*channels), order="F"), shape=(r, r, r, len(channels)))


class Carved:
    """An emptiness mask (:mod:`mitsnerf.math.carve`) as a factor on a density: ``keep(x)`` is 1 in a kept voxel of
    the ``R^3`` mask over ``box``, 0 in a carved one (the voxel holding ``x``; a constant, without gradient).

    >>> import mitsuba as mi
    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> from mitsnerf.math.box import UNIT_BOX
    >>> keep = np.ones((2, 2, 2), dtype=bool); keep[:, :, 0] = False          # the half x < 0 carved
    >>> mask = Carved(keep, UNIT_BOX)
    >>> mask(mi.Array3f([-0.3, -0.01, 0.01, 0.3], 0.0, 0.2)), mask.kept_fraction
    ([0, 0, 1, 1], 0.5)
    """

    def __init__(self, keep: np.ndarray, box: Box) -> None:
        import mitsuba as mi

        self.keep = np.asarray(keep, dtype=bool)
        self.box = box
        self._texture = mi.Texture3f(mi.TensorXf(self.keep.astype(np.float32)[..., None]), use_accel=False,
                                     filter_mode=dr.FilterMode.Nearest, wrap_mode=dr.WrapMode.Clamp)

    @property
    def kept_fraction(self) -> float:
        """Share of the voxels kept."""
        return float(self.keep.mean())

    def __call__(self, x):
        return self._texture.eval(self.box.to_unit(dr.detach(x)))[0]


@dataclass(frozen=True)
class GridMediumConfig:
    """Activations and starts of the grid medium."""

    sigma_scale: float = param(10.0, lo=0.0, lo_open=True)
    """``sigma = sigma_scale * act(s)``."""
    sigma_init: float = param(0.1, lo=0.0, lo_open=True)
    """Initial density everywhere (world units^-1)."""
    density_activation: str = param("softplus", choices=("softplus", "relu"))
    """After the trilinear lookup: ``softplus(s)`` (smooth, never 0), or ``max(s, 0)``: then a grid of the true
    values divided by ``sigma_scale`` is the true medium, trilinear as Mitsuba's gridvolume."""
    albedo_activation: str = param("sigmoid", choices=("sigmoid", "clamp"))
    """After the trilinear lookup: ``sigmoid(q)``, or ``clip(q, 0, 1)``."""

    def __post_init__(self) -> None:
        check_fields(self)

    def raw_sigma(self, sigma: np.ndarray) -> np.ndarray:
        """The density grid's values ``s`` that give ``sigma`` (numpy; the inverse of the activation).

        >>> GridMediumConfig(density_activation="relu").raw_sigma(np.array([0.0, 5.0])).tolist()
        [0.0, 0.5]
        """
        y = np.asarray(sigma, np.float64) / self.sigma_scale
        if self.density_activation == "relu":
            return y
        return y + np.log(-np.expm1(-np.maximum(y, 1e-30)))

    def raw_albedo(self, albedo: np.ndarray) -> np.ndarray:
        """The albedo grid's values ``q`` that give ``albedo`` (numpy)."""
        a = np.asarray(albedo, np.float64)
        if self.albedo_activation == "clamp":
            return a
        a = np.clip(a, 1e-6, 1.0 - 1e-6)
        return np.log(a / (1.0 - a))


class GridMedium:
    """Three grids (Dr.Jit tensors, their AD graphs kept): ``sigma_raw`` (R, R, R, C), ``albedo_raw`` (R_a, R_a,
    R_a, 3), ``rest`` (R_r, R_r, R_r, 3 K); each at its own resolution."""

    KEYS = ("sigma_raw", "albedo_raw", "rest")

    def __init__(self, config: GridMediumConfig, sigma_raw, albedo_raw, rest, box: Box) -> None:
        for name, grid in zip(self.KEYS, (sigma_raw, albedo_raw, rest)):
            if grid.ndim != 4 or (name == "albedo_raw" and grid.shape[-1] != 3) or grid.shape[-1] < 1:
                raise ValueError(f"grid medium: {name} has shape {tuple(grid.shape)}, expected (R, R, R, C)")
        self.config, self.box = config, box
        self.params = dict(zip(self.KEYS, (sigma_raw, albedo_raw, rest)))
        self._tex = {k: texture(v) for k, v in self.params.items()}

    @classmethod
    def create(cls, config: GridMediumConfig, resolutions: tuple[int, int, int], TensorXf, box: Box,
               density_channels: int, rest_first: np.ndarray, albedo_init: float) -> GridMedium:
        """Uniform grids at ``resolutions`` (density, albedo, rest): ``sigma_init``, ``albedo_init``, and every
        cell's remainder coefficients ``rest_first`` (3 K,)."""
        r, ra, rr = (int(v) for v in resolutions)
        sigma = dr.full(TensorXf, float(config.raw_sigma(np.float64(config.sigma_init))), (r, r, r, density_channels))
        albedo = dr.full(TensorXf, float(config.raw_albedo(np.float64(albedo_init))), (ra, ra, ra, 3))
        rest = TensorXf(np.ascontiguousarray(np.broadcast_to(rest_first.astype(np.float32), (rr, rr, rr,
                                                                                              len(rest_first)))))
        return cls(config, sigma, albedo, rest, box)

    def with_params(self, values: Mapping[str, Any]) -> GridMedium:
        p = {**self.params, **values}
        return GridMedium(self.config, p["sigma_raw"], p["albedo_raw"], p["rest"], self.box)

    @property
    def density_channels(self) -> int:
        return int(self.params["sigma_raw"].shape[-1])

    @property
    def n_rest(self) -> int:
        """3 K: the remainder's values per point."""
        return int(self.params["rest"].shape[-1])

    def density(self, x):
        raw = self._tex["sigma_raw"].eval(self.box.to_unit(x))
        act = softplus if self.config.density_activation == "softplus" else (lambda v: dr.maximum(v, 0.0))
        return extinction([self.config.sigma_scale * act(v) for v in raw], type(x))

    def lookup(self, x):
        p = self.box.to_unit(x)
        act = sigmoid if self.config.albedo_activation == "sigmoid" else (lambda v: dr.clip(v, 0.0, 1.0))
        albedo = type(x)(*(act(v) for v in self._tex["albedo_raw"].eval(p)))
        return self.density(x), albedo, list(self._tex["rest"].eval(p))

    def shadow_density(self, resolution: int):
        """The grid's own density (exact: the march looks it up wherever it samples)."""
        return self.density


@dataclass(frozen=True)
class HashMediumConfig(HashGridConfig):
    """Sizes of the hash medium: its hash grid (:class:`~mitsnerf.fields.hashgrid.HashGridConfig`, the ngp field's
    declaration and defaults: 3 levels from 16 to 24) and its two MLPs."""

    hidden: int = param(64, lo=1)
    """Width of the density MLP's hidden layer."""
    features: int = param(15, lo=1)
    """Features passed from the density MLP to the albedo-and-remainder MLP."""
    color_hidden: int = param(64, lo=1)
    """Width of the albedo-and-remainder MLP's hidden layer."""


class HashMedium:
    """The hash grid and its two MLPs (module docstring); ``params`` by dotted key, as the ngp field's."""

    def __init__(self, config: HashMediumConfig, TensorXf, box: Box, density_channels: int, rest_first: np.ndarray,
                 albedo_init: float, seed: int = 0, params: Mapping[str, Any] | None = None) -> None:
        self.config, self.TensorXf, self.box = config, TensorXf, box
        self._channels, self._n_rest = int(density_channels), len(rest_first)
        rng = dr.rng(seed=seed)
        self.encoding = config.encoding(TensorXf, rng)
        if params is None:
            n_in = config.n_features
            params = {"encoding.data": self.encoding.data,
                      **dense_init([n_in, config.hidden, self._channels + config.features], TensorXf, rng, "density."),
                      **dense_init([config.features, config.color_hidden, 3 + self._n_rest], TensorXf, rng,
                                   "color.")}
            start = np.concatenate([np.full(3, np.log(albedo_init / (1.0 - albedo_init))), rest_first])
            params["color.1.bias"] = TensorXf(start.astype(np.float32))
        self.params = dict(params)
        self.encoding.data = self.params["encoding.data"]
        self.rest_first = np.asarray(rest_first)
        self.albedo_init, self.seed = float(albedo_init), int(seed)

    def with_params(self, values: Mapping[str, Any]) -> HashMedium:
        return HashMedium(self.config, self.TensorXf, self.box, self._channels, self.rest_first, self.albedo_init,
                          self.seed, {**self.params, **values})

    @property
    def density_channels(self) -> int:
        return self._channels

    @property
    def n_rest(self) -> int:
        return self._n_rest

    def _density_mlp(self, x):
        features = self.encoding(dr.clip(self.box.to_unit(x), 0.0, 1.0))
        return dense_apply(self.params, "density.", 2, rows_tensor(self.TensorXf, features, dr.width(x)))

    def _sigma(self, out, Array3f):
        return extinction([dr.exp(dr.minimum(column(out, k), SIGMA_RAW_MAX)) for k in range(self._channels)],
                          Array3f)

    def density(self, x):
        return self._sigma(self._density_mlp(x), type(x))

    def lookup(self, x):
        out = self._density_mlp(x)
        c = dense_apply(self.params, "color.", 2, out[:, self._channels:])
        albedo = type(x)(*(sigmoid(column(c, k)) for k in range(3)))
        return self._sigma(out, type(x)), albedo, [column(c, 3 + k) for k in range(self._n_rest)]

    def shadow_density(self, resolution: int):
        """Its density sampled at the centres of a ``resolution^3`` grid (kept in the AD graph), looked up
        trilinearly: the proxy the transmittance cache marches through."""
        import mitsuba as mi

        tex = texture(grid_of(self.density(cell_centres(self.box, resolution, mi.Array3f)), resolution,
                              self.TensorXf))
        return lambda x: extinction(tex.eval(self.box.to_unit(x)), type(x))


Medium = GridMedium | HashMedium


def rest_start(rest_init: Sequence[float], n_rest: int) -> np.ndarray:
    """The remainder's starting coefficients (3 K,): incident radiance ``rest_init`` (RGB) from every direction,
    i.e. the order-0 coefficient ``sqrt(4 pi) rest_init`` (``Y_00 = 1 / sqrt(4 pi)``), the rest 0.

    >>> rest_start((1.0, 0.0, 0.5), 6).round(4).tolist()
    [3.5449, 0.0, 1.7725, 0.0, 0.0, 0.0]
    """
    out = np.zeros(n_rest)
    out[:3] = np.asarray(rest_init, np.float64) * math.sqrt(4.0 * math.pi)
    return out
