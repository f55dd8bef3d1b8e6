"""``mlp``: a network method, a small ``drjit.nn`` MLP field, as one file registered without installing anything.

    MITSNERF_METHODS=mlp=examples/mlp_method.py:MLPModel mitsnerf methods --check mlp
    MITSNERF_METHODS=mlp=examples/mlp_method.py:MLPModel mitsnerf train DATASET --method mlp

The field, ``(x, d) -> (rgb, sigma)`` on the M sample points of a batch of rays, as (C, M) tensors::

    p     = box.to_unit(x)                                  in [0, 1]^3, (3, M)
    h     = SinEncode(L)(p)                                 (3 * 2L, M): sin, cos of 2 pi 2^k p, k < L
    h     = ReLU(Linear(h))                                 `depth` hidden layers of `width`
    out   = Linear(h)                                       (4, M)
    sigma = sigma_scale * softplus(out_0)                   the density: softplus, never exp (below)
    rgb   = c_max * sigmoid(out_1..3)                       the colour: bounded, in (0, c_max)

rendered by the harness's own quadrature (``mitsnerf.render.volume.render_rays``: stratified samples between
each ray's entry into and exit from the scene box, composited over the scene's background).

Which activation for the density: ``mitsnerf.math.activations.softplus``, ``log(1 + e^x)``, as the package's own
nerf and voxel fields. The density must be >= 0 and finite. softplus's slope lies in (0, 1], so the density
grows at most linearly with the pre-activation, and it returns x itself above 15, so it is finite, with slope
1, for every float32 input. A hand-written ``dr.exp(x)`` (or ``drjit.nn.Exp``) is unbounded in value and slope:
where the fit wants density its gradient grows with the density itself, and above x = 88.7 float32 overflows,
exp and its gradient are inf, and the step's loss or gradients become NaN (training stops: "loss became nan").
A hand-written ``dr.log(1 + dr.exp(x))`` overflows there too, to inf with a zero gradient that never brings it
back. (``ngp``'s exp is clamped at 15, ``mitsnerf.fields.ngp.SIGMA_RAW_MAX``, for that reason.) The output
layer's density bias starts at ``sigma_bias = -2``: the medium starts nearly transparent (sigma = 1.3 per unit
length at ``sigma_scale = 10``), and the colour at 1/2 (``colour_bias``).

Trained at its tiny settings (below, with ``n_samples = 16``) for 300 steps of 256 rays on a 16^3 cloud in 8 views
of 16 x 16 pixels, it reaches that dataset's noise floor (28.9 dB test PSNR, floor 28.2; ``tests/test_plugins.py``
holds a margin under it); ``ngp`` and ``voxel`` at their defaults reach 27.6 and 28.5 dB in the same 300 steps.

The network is a ``drjit.nn.Sequential`` allocated for tensors (``.alloc(mi.TensorXf, 3, rng)``): a mapping of
its weights by dotted key (``layers.1.weights``, ...), which is what ``parameters()`` returns and what the
trainer's ``drjit.opt.Adam`` takes as is. Its linear layers are applied by ``mitsnerf.fields.nerf.linear``:
the same ``W h + b`` as ``nn.Linear.__call__``, but with the bias gradient summed in a fixed order, so that a
run repeats, and resumes, bit for bit on any number of CPU threads (Dr.Jit's own broadcast sums it in
per-thread partial sums whose order the scheduling decides).
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType

import drjit as dr
import drjit.nn as nn
import mitsuba as mi

from mitsnerf.config import param
from mitsnerf.fields.nerf import colour_bias, linear
from mitsnerf.math.activations import sigmoid, softplus
from mitsnerf.methods.base import MethodConfig, RayModel, RenderOutput, check_shapes, cover_radiance
from mitsnerf.render.volume import render_rays


@dataclass(frozen=True)
class MLPConfig(MethodConfig):
    """Settings of the ``mlp`` example method (what ``--set`` and a bench file's ``config`` table set)."""

    octaves: int = param(4, lo=1, hi=16)
    """Frequencies L of the sine encoding of the position."""
    width: int = param(64, lo=1, hi=1024)
    """Width of the hidden layers."""
    depth: int = param(2, lo=1, hi=16)
    """Number of hidden layers."""
    n_samples: int = param(48, lo=1, hi=4096)
    """Stratified samples per ray."""
    sigma_scale: float = param(10.0, lo=0.0, lo_open=True)
    """Density per unit of the softplus (world units^-1)."""
    sigma_bias: float = param(-2.0)
    """Initial bias of the density's pre-activation (the medium starts nearly transparent)."""
    c_max: float = param(1.0, lo=0.0, lo_open=True)
    """Largest colour; raised to cover the brightest training pixel (``cover_radiance``)."""
    lr: float = param(5e-3, lo=0.0, lo_open=True)
    """Adam learning rate."""


def build_network(config: MLPConfig, seed: int) -> nn.Sequential:
    """The MLP of ``config``, its weights drawn from ``seed`` alone; the output layer's biases start the density at
    ``softplus(sigma_bias)`` and the colour at 1/2."""
    layers: list[nn.Module] = [nn.SinEncode(config.octaves)]
    for _ in range(config.depth):
        layers += [nn.Linear(-1, config.width), nn.ReLU()]
    layers.append(nn.Linear(-1, 4))
    net = nn.Sequential(*layers).alloc(mi.TensorXf, 3, dr.rng(seed=seed))
    net.layers[-1].bias = mi.TensorXf([config.sigma_bias] + [colour_bias(config.c_max)] * 3)
    return net


class MLPField:
    """The field of a network: ``(x, d) -> (rgb, sigma)``, and ``density(x)``, on Array3f points (module docstring)."""

    def __init__(self, net: nn.Sequential, config: MLPConfig, box) -> None:
        self.net, self.config, self.box = net, config, box

    def _out(self, x) -> mi.TensorXf:
        """The network's (4, M) output at M points."""
        p = self.box.to_unit(x)
        h = mi.TensorXf(dr.ravel(p, order="C"), shape=(3, dr.width(p)))
        for layer in self.net.layers:
            h = linear(layer, h) if isinstance(layer, nn.Linear) else layer(h)
        return h

    def density(self, x):
        return self.config.sigma_scale * softplus(self._out(x)[0].array)

    def __call__(self, x, d):
        out = self._out(x)
        rgb = mi.Array3f(*(self.config.c_max * sigmoid(out[k].array) for k in (1, 2, 3)))
        return rgb, self.config.sigma_scale * softplus(out[0].array)


class MLPModel(RayModel):
    """A per-ray method: the MLP field rendered by the harness's quadrature."""

    config_type = MLPConfig
    description = "a small drjit.nn MLP field (examples/mlp_method.py)"
    tiny = MappingProxyType({"octaves": 2, "width": 16, "depth": 1, "n_samples": 8})

    def __init__(self, config: MLPConfig, scene, seed: int = 0) -> None:
        self.config, self.scene = cover_radiance(config, scene), scene
        self.mlp = MLPField(build_network(self.config, seed), self.config, scene.box)

    def parameters(self):
        return self.mlp.net  # a drjit.nn module is a mapping: layers.1.weights, layers.1.bias, ...

    def set_parameters(self, values) -> None:  # the optimiser's values, after every step
        check_shapes(self.mlp.net, values)
        self.mlp.net.update(values)

    def field(self) -> MLPField:  # HasField: the density scores and `mitsnerf export` read field().density(x)
        return self.mlp

    def samples_per_ray(self) -> int:
        return self.config.n_samples

    def render_rays(self, o, d, *, u=None, training: bool = False) -> RenderOutput:
        s = self.scene
        return RenderOutput(render_rays(self.mlp, o, d, self.config.n_samples, box=s.box, u=u,
                                        background=s.background))
