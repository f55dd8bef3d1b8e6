"""Output activations of fields, on any Dr.Jit array type.

    softplus(x) = log(1 + exp(x))        (x when x > 15, where the two agree in float32)
    sigmoid(x)  = 1 / (1 + exp(-x))

>>> from drjit.llvm import Float
>>> softplus(Float(0.0, 20.0))  # doctest: +ELLIPSIS
[0.6931..., 20]
>>> sigmoid(Float(0.0))
[0.5]
"""

from __future__ import annotations

import drjit as dr


def softplus(x):
    """``log(1 + exp(x))``, computed stably (drjit has no log1p)."""
    return dr.select(x > 15.0, x, dr.log(1.0 + dr.exp(dr.minimum(x, 15.0))))


def sigmoid(x):
    """``1 / (1 + exp(-x))``."""
    return 1.0 / (1.0 + dr.exp(-x))
