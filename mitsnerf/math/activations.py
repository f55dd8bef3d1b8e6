"""Output activations of fields, on any Dr.Jit array type.

    softplus(x) = log(1 + exp(x))        (x when x > 15, where the two agree in float32)
    sigmoid(x)  = 1 / (1 + exp(-x))
    colour_bias(c_max, c_0) = logit(c_0 / c_max)    (c_max sigmoid(b) = c_0: where a bounded colour starts)

>>> from drjit.llvm import Float
>>> softplus(Float(0.0, 20.0))  # doctest: +ELLIPSIS
[0.6931..., 20]
>>> sigmoid(Float(0.0))
[0.5]
"""

from __future__ import annotations

import math

import drjit as dr


def softplus(x):
    """``log(1 + exp(x))``, computed stably (drjit has no log1p)."""
    return dr.select(x > 15.0, x, dr.log(1.0 + dr.exp(dr.minimum(x, 15.0))))


def sigmoid(x):
    """``1 / (1 + exp(-x))``."""
    return 1.0 / (1.0 + dr.exp(-x))


def colour_bias(c_max: float, c_0: float = 0.5) -> float:
    """The pre-activation ``b = logit(c_0 / c_max)`` at which a colour ``c_max sigmoid(b)`` is ``c_0`` (the middle
    of ``[0, 1]``) whatever ``c_max`` is; 0 at ``c_max = 1``.

    Where every field's bounded colour starts (nerf's head bias, the band-0 SH coefficient of voxel's and
    primitives' colours): ``c_max`` follows the brightest training pixels
    (:func:`mitsnerf.methods.base.cover_radiance`), and a start at ``c_max / 2``, brighter than the medium, made the
    fit clear the density, the quickest way to darken every pixel (docs/notes/physics-table.md, "nerf's empty
    medium on cloud_hg85" and "The table at 88c2ab4").

    >>> colour_bias(1.0), round(colour_bias(12.0), 4)
    (0.0, -3.1355)
    """
    return math.log(c_0 / (c_max - c_0)) if c_max > c_0 else 0.0
