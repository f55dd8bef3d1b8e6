"""The instant-ngp field: a multiresolution hash-grid encoding and two tiny MLPs.

Architecture (Mueller et al. 2022, sizes configurable)::

    p       = box.to_unit(x)                                              in [0, 1]^3
    h(p)    = [trilinear lookup of level l's table at p * N_l]_{l < L}    (drjit.nn.HashGridEncoding)
              N_l = N_min * b^l,  b = (N_max / N_min)^(1 / (L - 1)); a level is a dense grid
              while it fits in 2^T entries, a hash table of 2^T entries beyond
    [s, g]  = MLP_sigma(h)                  one hidden layer, ReLU; g: geometry features
    sigma   = exp(min(s + sigma_bias, 15))                                (position only)
              (density_channels = 3: s has 3 entries, one extinction per colour, for chromatic media)
    c       = c_max * sigmoid(MLP_c([g, SH_0..(L_sh+1)^2-1(d)]))          (features + direction)

Grid sizes and SH degrees measured on the default cloud (64^3 fBm, 40 training views at
64 spp, whose noise is ~32 dB on medium pixels; 600 steps of 2048 rays), test PSNR
(medium pixels):

    16 levels to 256, SH degree 3 (680 steps):        39.6 dB (30.9)  train 48.5: fits the noise
    12 levels to 128, SH degree 2:                    39.4 dB (30.7)
     8 levels to  64, SH degree 1:                    40.6 dB (32.0)
     8 levels to  64, SH degree 0:                    43.4 dB (34.7)

Capacity above the data's own resolution, and any direction input, let the field follow
the training views' per-pixel noise; the defaults (:class:`NGPConfig`: 3 levels from 16
to 24, SH degree 0) are smaller still. The library's scenes but ``cloud_hg*`` have an isotropic
phase function, so their exact emission ``albedo * J(x)`` does not depend on the
direction; ``sh_degree`` 1-3 remain for anisotropic media or foreign data.

The MLPs are point-major tensor products (:mod:`mitsnerf.fields.mlp`), the fastest
path measured on the LLVM backend, or ``drjit.nn`` cooperative vectors on the same parameters
(``network_path``; ``auto``: tensors, :func:`mitsnerf.fields.mlp.network_path`). The hash table is one flat Float
array kept by the
field (``encoding.data``), apart from the MLPs: ``drjit.nn`` does not pack it.
Its size matters on this CPU: forward + backward of 16 levels measured 10 ms per
2^16 points with 2^15 entries per level, 80 ms with 2^16 (the scattered
gradients stop fitting in cache).
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import drjit.nn as nn

from mitsnerf.config import param
from mitsnerf.fields.grid import extinction
from mitsnerf.fields.hashgrid import HashGridConfig
from mitsnerf.fields.mlp import (
    NETWORK_PATHS,
    column,
    coop_apply,
    dense_apply,
    dense_apply_coop,
    dense_init,
    network_path,
    pack_layers,
    rows_tensor,
    usable_network_paths,
)
from mitsnerf.fields.sh import MAX_DEGREE, num_coefficients, sh_basis
from mitsnerf.math.activations import sigmoid
from mitsnerf.math.box import Box

SIGMA_RAW_MAX = 15.0
"""Largest density pre-activation: ``exp(15)`` is far beyond any medium here and keeps float32 finite."""


@dataclass(frozen=True)
class NGPConfig(HashGridConfig):
    """Sizes of the hash grid (:class:`~mitsnerf.fields.hashgrid.HashGridConfig`) and the MLPs of the ngp field.

    The defaults suit 64-pixel views of 64^3 media trained from 64-spp images: with 8 levels up to
    64 the grid memorised the training noise (train PSNR 52 dB, test 41.6 dB on the default cloud
    after 1700 steps of 2048 rays); 3 levels from 16 to 24 gave 47.7 dB test (39.0 dB on medium
    pixels) in the same steps. Finer media or larger images want a larger ``max_resolution``.
    """

    hidden: int = param(64, lo=1)
    """Width of the density MLP's hidden layer."""
    geo_features: int = param(15, lo=1)
    """Features passed from the density MLP to the colour MLP."""
    color_hidden: int = param(64, lo=1)
    """Width of the colour MLP's hidden layers."""
    color_layers: int = param(1, lo=0)
    """Hidden layers of the colour MLP (instant-ngp: 2)."""
    sh_degree: int = param(0, lo=0, hi=MAX_DEGREE)
    """Highest SH band of the direction encoding (0: constant, no direction input)."""
    sigma_bias: float = param(0.0)
    """Added to the density pre-activation (0: sigma starts near 1)."""
    density_channels: int = param(1, choices=(1, 3))
    """1: one density for every colour; 3: one per colour channel (chromatic media, a 3-channel sigma_t)."""
    c_max: float = param(1.0, lo=0.0, lo_open=True)
    """Largest colour (radiance) the colour MLP can output."""
    network_path: str = param("auto", choices=NETWORK_PATHS)
    """How the MLPs are evaluated (:func:`mitsnerf.fields.mlp.network_path`): point-major tensors or
    cooperative vectors (fp32, fp16: its training gradients are wrong at batch sizes), on the same
    parameters; ``auto``: tensors."""
    split_k: int = param(-1, lo=-1)
    """Tensor path: each product's split-k batches (:func:`mitsnerf.fields.mlp.matmul_rows`); -1: the backend's
    default (:func:`mitsnerf.fields.mlp.gemm_split_k`: 64 on CUDA, one product on LLVM), 0 or 1: one product."""


class NGPField:
    """The field callable ``(x, d) -> (rgb, sigma)``; also ``density(x)``.

    >>> import mitsuba as mi
    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> from mitsnerf.math.box import UNIT_BOX
    >>> f = NGPField(NGPConfig(n_levels=4, max_resolution=32, hidden=16, color_hidden=16), mi.TensorXf, UNIT_BOX)
    >>> rgb, sigma = f(mi.Array3f([0.0, 0.1], 0.0, 0.0), mi.Array3f(0, 0, 1))
    >>> dr.width(sigma), bool(dr.all((sigma > 0.9) & (sigma < 1.1)))
    (2, True)
    """

    def __init__(self, config: NGPConfig, TensorXf, box: Box, seed: int = 0) -> None:
        network_path(config.network_path, TensorXf)  # a path this backend lacks: refused here, not mid-run
        self.config = config
        self.TensorXf = TensorXf
        self.box = box
        rng = dr.rng(seed=seed)
        self.encoding = config.encoding(TensorXf, rng)
        n_in = config.n_features
        n_dir = num_coefficients(config.sh_degree)
        self.params = {
            "encoding.data": self.encoding.data,
            **dense_init([n_in, config.hidden, config.density_channels + config.geo_features], TensorXf, rng,
                         "density."),
            **dense_init([config.geo_features + n_dir] + [config.color_hidden] * config.color_layers + [3],
                         TensorXf, rng, "color."),
        }
        """Every trainable value by dotted key: ``encoding.data`` (the hash tables, Float (n,)),
        ``density.{l}.weights|bias`` and ``color.{l}.weights|bias`` (point-major layers)."""

    def set_parameters(self, values) -> None:
        """Take new values for (a subset of) :attr:`params` (unknown keys are an error)."""
        unknown = sorted(set(values) - set(self.params))
        if unknown:
            raise KeyError(f"ngp field: unknown parameters {unknown}")
        self.params.update(values)
        self.encoding.data = self.params["encoding.data"]

    # -- evaluation ----------------------------------------------------------------

    def _coop_half(self) -> bool | None:
        """None on the tensor path; on cooperative vectors, whether in fp16."""
        path = network_path(self.config.network_path, self.TensorXf)
        return None if path == "tensor" else path == "coopvec-fp16"

    def _features(self, x):
        """The hash-grid encoding of ``x``: n_levels * features_per_level Floats."""
        return self.encoding(dr.clip(self.box.to_unit(x), 0.0, 1.0))

    def _density_coop(self, x, half: bool) -> list:
        """density_channels + geo_features Floats: the density MLP on cooperative vectors (fp16 if ``half``)."""
        return dense_apply_coop(self.params, "density.", 2, nn.CoopVec(*self._features(x)), half)

    def _density_mlp(self, x):
        """(M, density_channels + geo_features): the density pre-activations and the geometry features (tensor
        path)."""
        rows = rows_tensor(self.TensorXf, self._features(x), dr.width(x))
        return dense_apply(self.params, "density.", 2, rows, slices=self._split_k)

    @property
    def _split_k(self) -> int | None:
        """``split_k`` as :func:`dense_apply`'s ``slices`` (None: the backend's default)."""
        return None if self.config.split_k < 0 else self.config.split_k

    @property
    def sigma_channels(self) -> int:
        """The density's channels: 1, or 3 (``sigma`` an Array3f, one extinction per colour)."""
        return self.config.density_channels

    def _sigma(self, raw: list, Array3f):
        """``sigma`` from the density pre-activations (a list of ``density_channels`` Floats)."""
        return extinction([dr.exp(dr.minimum(v + self.config.sigma_bias, SIGMA_RAW_MAX)) for v in raw], Array3f)

    def _raw_columns(self, out) -> list:
        return [column(out, k) for k in range(self.config.density_channels)]

    def density(self, x):
        """``sigma(x)``, Float (M,) (an Array3f with ``density_channels = 3``)."""
        half = self._coop_half()
        n = self.config.density_channels
        if half is not None:
            return self._sigma(list(self._density_coop(x, half)[:n]), type(x))
        return self._sigma(self._raw_columns(self._density_mlp(x)), type(x))

    def loop_field(self) -> PackedNGP:
        """This field for a symbolic loop (:mod:`mitsnerf.render.replay`): the MLPs on cooperative vectors, their
        weights packed once, here (fp16 on ``coopvec-fp16``, fp32 otherwise: the tensor path's batch-wide
        tensors cannot live in a loop). fp32 needs a backend with ``coopvec-fp32`` (not CUDA):
        :meth:`loop_refusal` says why not."""
        why = self.loop_refusal()
        if why is not None:
            raise ValueError(f"loop_field: {why}")
        return PackedNGP(self, half=self._coop_half() is True)

    def loop_refusal(self) -> str | None:
        """Why :meth:`loop_field` cannot run on this backend with this ``network_path``, or None."""
        if self._coop_half() is True or "coopvec-fp32" in usable_network_paths(self.TensorXf):
            return None
        return ("a loop evaluates the MLPs on fp32 cooperative vectors unless network_path = coopvec-fp16 "
                f"(it is {self.config.network_path}), and this backend has none")

    def __call__(self, x, d):
        width = dr.width(x)
        if dr.width(d) != width:
            d = d + dr.zeros(type(d), width)
        sh = sh_basis(d, self.config.sh_degree)
        n_color = self.config.color_layers + 1
        half = self._coop_half()
        n = self.config.density_channels
        if half is not None:
            out = self._density_coop(x, half)
            c = dense_apply_coop(self.params, "color.", n_color, nn.CoopVec(*out[n:], *sh), half)
            return type(x)(*(sigmoid(c_k) * self.config.c_max for c_k in c)), self._sigma(list(out[:n]), type(x))
        out = self._density_mlp(x)
        sh_rows = rows_tensor(self.TensorXf, sh, width)
        rows = dr.concat([out[:, n:], sh_rows], axis=1)
        c = (
            sigmoid(dense_apply(self.params, "color.", n_color, rows, slices=self._split_k))
            * self.config.c_max
        )
        return type(x)(column(c, 0), column(c, 1), column(c, 2)), self._sigma(self._raw_columns(out), type(x))


class PackedNGP:
    """:class:`NGPField` evaluated per point with pre-packed MLP weights (:meth:`NGPField.loop_field`): a field
    callable ``(x, d) -> (rgb, sigma)`` a ``dr.while_loop`` can record and differentiate, gradients reaching the
    field's :attr:`~NGPField.params` (the hash tables directly, the weights through the packing)."""

    def __init__(self, field: NGPField, half: bool) -> None:
        self.field, self.half = field, half
        cfg = field.config
        self.n_color = cfg.color_layers + 1

        def names(prefix: str, n: int) -> list:
            return [f"{prefix}{i}.{kind}" for i in range(n) for kind in ("weights", "bias")]

        self.density_views = pack_layers([field.params[k] for k in names("density.", 2)], half)
        self.color_views = pack_layers([field.params[k] for k in names("color.", self.n_color)], half)

    def __call__(self, x, d):
        f = self.field
        width = dr.width(x)
        if dr.width(d) != width:
            d = d + dr.zeros(type(d), width)
        out = coop_apply(self.density_views, 2, nn.CoopVec(*f._features(x)), self.half)
        sh = sh_basis(d, f.config.sh_degree)
        n = f.config.density_channels
        c = coop_apply(self.color_views, self.n_color, nn.CoopVec(*out[n:], *sh), self.half)
        return type(x)(*(sigmoid(c_k) * f.config.c_max for c_k in c)), f._sigma(list(out[:n]), type(x))
