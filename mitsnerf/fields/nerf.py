"""The NeRF field ``F(x, d) -> (c, sigma)`` as a ``drjit.nn`` network in tensor mode.

Architecture (Mildenhall et al. 2020, sizes configurable: NeRF's encodings and skip connection on a
CPU-sized trunk of 4 x 64 instead of 8 x 256)::

    p      = box.to_unit(x)                                       in [0, 1]^3
    gamma(p) = [p, sin(2 pi 2^k p), cos(2 pi 2^k p)]_{k < L_x}     (drjit.nn.SinEncode, period 1)
    h      = MLP_trunk(gamma(p))        depth D, width W, ReLU, the input re-injected at `skip`
    sigma  = softplus(h_0 + sigma_bias) * sigma_scale              (position only)
    c      = c_max * sigmoid(MLP_head([h_1.., gamma((d + 1) / 2)]))  (features [+ direction])
             the head's output bias starts at logit(1 / (2 c_max)): c starts at 1/2 (colour_bias)

``gamma((d + 1) / 2)`` is NeRF's ``sin(2^k pi d)`` up to sign, for ``d`` in ``[-1, 1]^3``.

The defaults differ from NeRF in two settings, both measured on the default cloud (800 steps,
docs/notes/nerf.md, "nerf: the view direction"): no direction input (``use_direction = False``)
and 4 position octaves instead of 10. The library's scenes but ``cloud_hg*`` have an isotropic phase
function, so the emission ``albedo J(x)`` that every pixel integrates does not depend on the view
direction; a colour head that takes it can explain each training view's image with a wrong
density instead (NeRF++'s shape-radiance ambiguity): 30.5 dB on medium pixels with NeRF's 4
direction octaves, 32.0 with 2, 36.2 with the raw direction, 36.9 without any, and 38.3 without
it at 4 position octaves. ``use_direction = true`` (``dir_octaves = 4``: NeRF's) stays for
anisotropic media and foreign data. ``ngp`` made the same choice (SH degree 0).

Two ways to evaluate the same parameters (``network_path``): tensor mode, a (C, M) tensor through
``nn.Linear``'s weights and biases, and ``drjit.nn`` cooperative vectors, the weights packed by
``nn.pack`` on every pass (fp32, or fp16 copies for the tensor cores). ``auto`` takes tensor mode
(:func:`mitsnerf.fields.mlp.network_path`: 4-5x faster than cooperative vectors on the CPU; on CUDA
fp16 is faster per step but its gradients are wrong at training batch sizes). In tensor mode the
layers are evaluated by :func:`linear`, not ``nn.Linear.__call__``, so that their bias gradients are
summed in a fixed order (training runs are reproducible bit for bit); cooperative vectors accumulate
their gradients in their own order.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import drjit.nn as nn

from mitsnerf.config import Since, check_fields, param
from mitsnerf.fields.mlp import NETWORK_PATHS, network_path, pack_layers
from mitsnerf.math.activations import colour_bias, sigmoid, softplus
from mitsnerf.math.box import Box


@dataclass(frozen=True)
class NeRFConfig:
    """Sizes and output scalings of the NeRF network."""

    pos_octaves: int = param(4, lo=0, hi=20)
    """Frequencies L_x of the positional encoding of x (NeRF: 10; 4 measured better here, module docstring)."""
    use_direction: bool = param(False, since=Since("0.1.0+7225556", refuse="nerf fed every colour head the view "
                                                    "direction then, at twice today's frequency"))
    """Feed the encoded view direction to the colour head (NeRF: True); False (the default): the colour
    depends on position only, as the emission ``albedo J(x)`` of an isotropic medium does."""
    dir_octaves: int = param(4, lo=0, hi=20)
    """Frequencies L_d of the encoding of the view direction (NeRF: 4; unused without ``use_direction``)."""
    width: int = param(64, lo=1, hi=4096)
    """Width W of the trunk (NeRF: 256)."""
    depth: int = param(4, lo=1, hi=64)
    """Number of hidden layers D of the trunk (NeRF: 8)."""
    skip: int | None = param(2, lo=0, hi=64)
    """Trunk layer index at which the encoded input is concatenated again (NeRF: 4, of 8); None or 0
    (TOML has no null), or an index >= depth (a trunk too shallow for it): no skip."""
    features: int = param(15, lo=1, hi=4096)
    """Position features passed from the trunk to the colour head."""
    head_width: int = param(32, lo=1, hi=4096)
    """Width of the colour head's hidden layer (NeRF: 128)."""
    sigma_scale: float = param(10.0, lo=0.0, lo_open=True)
    """Output scale of sigma (world units^-1): softplus(h_0 + sigma_bias) * sigma_scale."""
    sigma_bias: float = param(-2.0)
    """Initial bias of the density pre-activation (starts nearly transparent)."""
    c_max: float = param(1.0, lo=0.0, lo_open=True)
    """Largest colour (radiance) the head can output."""
    network_path: str = param("auto", choices=NETWORK_PATHS)
    """How the layers are evaluated: ``tensor`` ((C, M) tensors and matrix products), ``coopvec-fp32`` /
    ``coopvec-fp16`` (``drjit.nn`` cooperative vectors, the weights packed each pass; on CUDA they run
    on the tensor cores; fp16 renders, but its training gradients are wrong at batch sizes, so it does not
    train: :func:`network_path`), or ``auto``: :func:`network_path` (tensors). The parameters are the same
    fp32 tensors on every path, so a run trained on one renders on another."""

    def __post_init__(self) -> None:
        check_fields(self)


class _BroadcastColumns(dr.CustomOp):
    """A (C,) vector repeated along M columns -> (C, M); its adjoint sums each row by ``dr.block_sum``.

    ``drjit.nn.Linear`` adds its bias as ``y + dr.reshape(b, (C, 1))``: a broadcast whose
    adjoint is a scatter-add of the C x M output gradients into the C biases. On the LLVM
    backend that scatter runs in ``ReduceMode.Expand`` (one copy of the target per worker
    thread, summed at the end), and which thread accumulates which block of points depends
    on scheduling, so the bias gradients change in the last bit from run to run. A block
    reduction sums each row in a fixed order.
    """

    def eval(self, b, m):
        self.c, self.m = b.shape[0], m
        return self._repeat(b)

    def _repeat(self, b):
        TensorXf = type(b)
        Float = dr.leaf_t(TensorXf)
        row = dr.arange(dr.uint32_array_t(Float), self.c * self.m) // self.m
        return TensorXf(dr.gather(Float, b.array, row), shape=(self.c, self.m))

    def forward(self):
        self.set_grad_out(self._repeat(self.grad_in("b")))

    def backward(self):
        g = self.grad_out()
        self.set_grad_in("b", type(g)(dr.block_sum(g.array, self.m), shape=(self.c,)))

    def name(self):
        return "broadcast_columns"


def linear(layer, x):
    """``W x + b`` of an ``nn.Linear`` ``layer`` on a (C_in, M) tensor -> (C_out, M).

    The same values as ``layer(x)``, but the bias gradient is a per-row block sum (fixed
    order) instead of Dr.Jit's broadcast adjoint, a multi-threaded scatter-add whose
    rounding depends on thread scheduling (:class:`_BroadcastColumns`).

    >>> import mitsuba as mi
    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> layer = nn.Linear(2, 3).alloc(mi.TensorXf, 2, dr.rng(seed=0))
    >>> x = dr.ones(mi.TensorXf, (2, 4))
    >>> bool(dr.all(linear(layer, x) == layer(x), axis=None))
    True
    """
    y = dr.matmul(layer.weights, x)  # not ``@``, which turns any failure of the product into a TypeError
    if layer.bias is None:
        return y
    return y + dr.custom(_BroadcastColumns, layer.bias, x.shape[1])


def _encode(values, octaves: int):
    """``[v, sin(2 pi 2^k v), cos(2 pi 2^k v)]_{k < L}`` of a (C, M) tensor -> (C (1 + 2L), M)."""
    if octaves == 0:
        return values
    return dr.concat([values, nn.SinEncode(octaves)(values)], axis=0)


class NeRFNetwork(nn.Module):
    """Trunk layers, density/feature output layer, colour head: a ``drjit.nn`` Module.

    Its mapping interface lists every weight and bias by dotted key
    (``trunk.0.weights``, ...), which is what ``drjit.opt`` optimisers take.
    """

    DRJIT_STRUCT = {"trunk": list, "out": nn.Linear, "head": list}

    def __init__(self, trunk, out, head):
        self.trunk = trunk
        self.out = out
        self.head = head


def build_network(config: NeRFConfig, TensorXf, seed: int = 0, head: bool = True) -> NeRFNetwork:
    """Allocate a network for ``config`` with weights from a seeded generator; ``head=False``: a
    density-only network (one output, no colour head: ``config.features`` and the head's sizes unused)."""
    rng = dr.rng(seed=seed)
    in_pos = 3 * (1 + 2 * config.pos_octaves)
    in_dir = 3 * (1 + 2 * config.dir_octaves) if config.use_direction else 0
    trunk = []
    size = in_pos
    for i in range(config.depth):
        if config.skip and i == config.skip:
            size += in_pos
        trunk.append(nn.Linear(size, config.width).alloc(TensorXf, size, rng))
        size = config.width
    features = config.features if head else 0
    out = nn.Linear(size, 1 + features).alloc(TensorXf, size, rng)
    out.bias = TensorXf([config.sigma_bias] + [0.0] * features)
    if not head:
        return NeRFNetwork(trunk, out, [])
    h1 = nn.Linear(config.features + in_dir, config.head_width).alloc(TensorXf, 0, rng)
    h2 = nn.Linear(config.head_width, 3).alloc(TensorXf, 0, rng)
    h2.bias = TensorXf([colour_bias(config.c_max)] * 3)
    return NeRFNetwork(trunk, out, [h1, h2])


@dataclass(frozen=True)
class NeRFField:
    """The field callable: ``(x, d) -> (rgb, sigma)`` through a :class:`NeRFNetwork`.

    >>> import mitsuba as mi
    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> from mitsnerf.math.box import UNIT_BOX
    >>> f = NeRFField.create(NeRFConfig(width=16, depth=2), mi.TensorXf, UNIT_BOX)
    >>> rgb, sigma = f(mi.Array3f([0.0, 0.1], 0.0, 0.0), mi.Array3f(0, 0, 1))
    >>> dr.width(sigma), bool(dr.all(sigma >= 0))
    (2, True)
    """

    config: NeRFConfig
    net: NeRFNetwork
    box: Box

    def __post_init__(self) -> None:
        network_path(self.config.network_path, type(self.net.out.weights))  # refused here if the backend lacks it

    @classmethod
    def create(cls, config: NeRFConfig, TensorXf, box: Box, seed: int = 0, head: bool = True) -> NeRFField:
        """A field of a freshly initialised network; ``head=False``: density only (:meth:`density`)."""
        return cls(config, build_network(config, TensorXf, seed, head), box)

    def _ops(self, width: int):
        """The layer operations of this field's :func:`network_path`, for ``width`` points."""
        TensorXf = type(self.net.out.weights)
        path = network_path(self.config.network_path, TensorXf)
        return _TensorOps(TensorXf, width) if path == "tensor" else _CoopOps(TensorXf, half=path == "coopvec-fp16")

    def _trunk(self, ops, x):
        enc = ops.encode(self.box.to_unit(x), self.config.pos_octaves)
        *trunk, out = ops.layers(self.net.trunk + [self.net.out])
        h = enc
        for i, layer in enumerate(trunk):
            if self.config.skip and i == self.config.skip:
                h = ops.concat(h, enc)
            h = dr.maximum(layer(h), 0.0)
        return out(h)

    def density(self, x):
        """``sigma(x)``, Float (M,)."""
        ops = self._ops(dr.width(x))
        return softplus(ops.first(self._trunk(ops, x))) * self.config.sigma_scale

    def __call__(self, x, d):
        ops = self._ops(dr.width(x))
        out = self._trunk(ops, x)
        sigma = softplus(ops.first(out)) * self.config.sigma_scale
        h = ops.rest(out)
        if self.config.use_direction:
            h = ops.concat(h, ops.encode(dr.fma(d, 0.5, 0.5), self.config.dir_octaves))
        head_1, head_2 = ops.layers(self.net.head)
        c = ops.rows(head_2(dr.maximum(head_1(h), 0.0)))
        return type(x)(*(sigmoid(c_k) * self.config.c_max for c_k in c)), sigma


class _TensorOps:
    """The network on (C, M) tensors: each layer by :func:`linear` (fixed-order bias gradients)."""

    def __init__(self, TensorXf, width: int) -> None:
        self.TensorXf, self.width = TensorXf, width

    def encode(self, v, octaves: int):
        """:func:`_encode` of an Array3f ``v`` (broadcast to the width) as a (3 (1 + 2L), M) tensor."""
        if dr.width(v) != self.width:
            v = v + dr.zeros(type(v), self.width)
        return _encode(self.TensorXf(dr.ravel(v, order="C"), shape=(3, self.width)), octaves)

    def concat(self, a, b):
        return dr.concat([a, b], axis=0)

    def layers(self, layers):
        return [lambda h, layer=layer: linear(layer, h) for layer in layers]

    def rows(self, out):
        """The rows of a (C, M) tensor, C Floats."""
        return [out[k].array for k in range(out.shape[0])]

    def first(self, out):
        return out[0].array

    def rest(self, out):
        return out[1:]


class _CoopOps:
    """The network on ``drjit.nn`` cooperative vectors, the layers' fp32 weights packed each pass by
    ``nn.pack`` (fp16 copies if ``half``): the gradients flow back through the packing to them."""

    def __init__(self, TensorXf, half: bool) -> None:
        Float = dr.leaf_t(TensorXf)
        self.Float, self.half = Float, half
        self.Half = dr.float16_array_t(Float)

    def encode(self, v, octaves: int):
        """``[v, sin(2 pi 2^k v), cos(2 pi 2^k v)]_{k < L}`` as a cooperative vector (:func:`_encode`'s order)."""
        cv = nn.CoopVec(v.x, v.y, v.z)
        if octaves:
            cv = nn.CoopVec(*cv, *nn.SinEncode(octaves)(cv))
        return nn.cast(cv, self.Half) if self.half else cv

    def concat(self, a, b):
        return nn.CoopVec(*a, *b)

    def layers(self, layers):
        """``nn.matvec`` of each layer on packed views of its weights and bias (:func:`pack_layers`)."""
        views = pack_layers([t for layer in layers for t in (layer.weights, layer.bias)], self.half)
        return [lambda h, w=w, b=b: nn.matvec(w, h, b) for w, b in zip(views[0::2], views[1::2])]

    def rows(self, out):
        return [self.Float(v) for v in out]

    def first(self, out):
        return self.Float(next(iter(out)))

    def rest(self, out):
        return nn.CoopVec(*list(out)[1:])
