"""Adam with its per-entry normaliser floored at a quantile of the parameter's second moments.

Plain Adam steps entry ``i`` of a parameter by ``lr * m_i / sqrt(v_i)`` (``m``, ``v`` its bias-corrected moment
averages): about ``lr`` whatever the size of the gradient, so an entry whose gradient is only noise random-walks as
far as one the data fixes. UniformAdam (Nicolet et al. 2021; ``drjit.opt.Adam(uniform=True)``) divides every entry by
the largest ``sqrt(v)`` of the parameter instead, so that an entry moves in proportion to its gradient; but the
largest is one entry's, and where a few entries' gradients dominate (a forward-scattering medium's sunlit rim) it
holds all the others still. Between the two, :class:`QuantileAdam` divides by the larger of the entry's own and the
``q``-quantile ``v_q`` of the parameter's nonzero second moments:

    step_i = -lr * m_i / sqrt(max(v_i, v_q))

Entries above the quantile step as Adam's, about ``lr``; the others in proportion to their gradient, the quantile's
entry by ``lr``. ``q = 1`` is UniformAdam, ``q = 0`` plain Adam but for the smallest entries.

>>> import drjit as dr, drjit.opt, mitsuba as mi, numpy as np
>>> _ = mi.set_variant("llvm_ad_rgb") if mi.variant() is None else None
>>> opt = QuantileAdam(lr=1.0, quantile=0.5)
>>> opt["x"] = mi.TensorXf(np.zeros(4, np.float32))
>>> dr.backward(dr.sum(opt["x"] * mi.TensorXf(np.array([-4.0, -2.0, -1.0, -0.5], np.float32)), axis=None))
>>> opt.step()
>>> np.round(np.asarray(opt["x"]), 3)  # above the median second moment by lr, the others in proportion
array([1.   , 1.   , 0.632, 0.316], dtype=float32)
"""

from __future__ import annotations

from typing import Any

import drjit as dr
import drjit.opt  # noqa: F401  (makes dr.opt available)
import numpy as np


def nonzero_quantile(v, q: float) -> float:
    """The ``q``-quantile of the nonzero entries of the flat array ``v`` (0 when none is): the entries a step's
    gradient reached, not those held at 0 (an emptiness mask's voxels)."""
    values = np.asarray(v, dtype=np.float64).ravel()
    values = values[values > 0]
    return float(np.quantile(values, q)) if values.size else 0.0


class QuantileAdam(dr.opt.Adam):
    """:mod:`drjit.opt`'s Adam with each entry's ``sqrt(v)`` floored at the ``quantile`` of the parameter's nonzero
    ones (the module docstring); its state (step count, moments) is Adam's, so checkpoints are too."""

    def __init__(self, lr: float, quantile: float, **kwargs: Any) -> None:
        if not 0.0 <= quantile <= 1.0:
            raise ValueError(f"quantile: must be in [0, 1], got {quantile}")
        super().__init__(lr, **kwargs)
        self.quantile = float(quantile)

    def _step(self, cache, value, grad, lr, extra, /):
        t_p, m_tp, v_tp, v_max_p = extra
        t = t_p + 1
        m_t = dr.lerp(grad, m_tp, self.beta_1)
        v_t = dr.lerp(dr.square(grad), v_tp, self.beta_2)
        dr.eval(m_t, v_t)
        v_q = nonzero_quantile(v_t, self.quantile)
        base = dr.leaf_t(grad)
        wide = dr.float64_array_t(base)  # t is an opaque counter: the debiasing stays out of the kernel's code
        debias = base(-dr.sqrt(1 - wide(self.beta_2) ** t) / (1 - wide(self.beta_1) ** t))
        scale = cache.product(base, lr, debias)
        step = m_t * dr.rsqrt(dr.maximum(v_t, v_q) + self.epsilon ** 2)
        return dr.fma(step, scale, value), (t, m_t, v_t, v_max_p)
