"""One training step's loss, by protocol: a random ray batch for per-ray models, the model's own for whole-view ones.

For a :class:`mitsnerf.methods.base.RendersRays` model (``B`` rays, targets ``C*``)::

    loss = mean_rays,channels (C - C*)^2 + sum extra_losses + sum_aux mean (C_aux - C*)^2
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from mitsnerf.methods.base import FollowsBudget, Model, RendersRays, Rows, StepLoss, TrainsOnPixels, TrainsOnViews
from mitsnerf.train.config import TrainConfig
from mitsnerf.train.data import PixelData
from mitsnerf.train.schedule import learning_rate, step_rng


def ray_batch_loss(model: RendersRays, data: PixelData, config: TrainConfig, rng) -> StepLoss:
    """Render ``config.batch_rays`` random training pixels (jittered training samples)."""
    B = config.batch_rays
    o, d, target = data.batch(rng, B, config.pixel_jitter)
    n = model.jitter_size()
    out = model.render_rays(o, d, u=rng.random(mi.Float, B * n) if n else None, training=True)
    mse = dr.mean(dr.square(out.rgb - target), axis=None)
    loss = mse
    for extra in out.extra_losses.values():
        loss = loss + extra
    for aux in (out.aux_rgb or {}).values():
        loss = loss + dr.mean(dr.square(aux - target), axis=None)
    return StepLoss(loss, mse, B)


def step_loss(model: Model, data: PixelData, config: TrainConfig, step: int, rng) -> StepLoss:
    """The step of ``model``'s capability (:class:`~mitsnerf.methods.base.RendersRays`,
    :class:`~mitsnerf.methods.base.TrainsOnPixels` with ``config.batch_rays`` pixels, or
    :class:`~mitsnerf.methods.base.TrainsOnViews`)."""
    if isinstance(model, RendersRays):
        return ray_batch_loss(model, data, config, rng)
    if isinstance(model, TrainsOnPixels):
        return model.pixel_batch_loss(data, config.batch_rays, step, rng)
    if isinstance(model, TrainsOnViews):
        return model.training_loss(data, step, rng)
    raise TypeError(f"{type(model).__name__}: a Model must render rays (RendersRays: subclass RayModel), train on "
                    "pixels (TrainsOnPixels: subclass PixelModel) or train on views (TrainsOnViews: subclass "
                    "ViewModel)")


def set_step_learning_rate(model: Model, opt, base_lr: float, step: int, config: TrainConfig) -> float:
    """Set ``opt``'s learning rate for ``step``: ``lr`` = :func:`~mitsnerf.train.schedule.learning_rate` of
    ``base_lr``, and ``lr * f`` for each parameter the model scales by ``f`` (``model.lr_scales(step)``; a
    :class:`~mitsnerf.methods.base.FollowsBudget` model is told the budget, ``config.steps``, first).
    Returns ``lr``."""
    if isinstance(model, FollowsBudget):
        model.set_budget(config.steps)
    lr = learning_rate(base_lr, step, config.steps, config.lr_final_factor)
    opt.set_learning_rate(lr)
    scales = {k: lr * float(f) for k, f in model.lr_scales(step).items() if k in opt}
    if scales:
        opt.set_learning_rate(scales)
    return lr


def bare_step(model: Model, opt, data: PixelData, config: TrainConfig, base_lr: float, step: int) -> float:
    """The trainer's step without its bookkeeping (no NaN check, log or checkpoint): the step's learning rate,
    its loss on the step's random numbers, backward, :func:`apply_step`; waits for the work to finish (for the
    benchmarks that time steps). Returns the loss."""
    set_step_learning_rate(model, opt, base_lr, step, config)
    out = step_loss(model, data, config, step, step_rng(config.seed, step))
    dr.backward(out.loss)
    loss = float(out.loss[0])
    apply_step(model, opt, step)
    dr.sync_thread()
    return loss


def apply_step(model: Model, opt, step: int) -> None:
    """The optimiser's step and what follows it (methods/base.py): the optimiser's values handed to the model,
    then the values the model returns from ``after_step`` (resampled, clamped) written into the optimiser and
    handed back (:class:`~mitsnerf.methods.base.Rows`: with the state of the rows they continue). ``opt``: a
    ``drjit.opt`` optimiser whose gradients are set."""
    opt.step()
    model.set_parameters(opt)
    new = model.after_step(step, opt)
    if new:
        sources = new.sources if isinstance(new, Rows) else {}
        before = {key: opt.state[key] for key in sources}
        opt.update(new)
        for key, rows in sources.items():
            carry_rows(opt, key, before[key], rows)
        model.set_parameters(opt)


def carry_rows(opt, key: str, before, sources) -> None:
    """Give parameter ``key`` of ``opt`` (just written with a value of new rows) the Adam moments of the rows its
    rows continue (``sources``: the old row of each new row, -1 for none: zero moments) from ``before`` (its
    ``opt.state`` entry before the write); its step count continues. Other optimisers' state restarts.

    >>> import drjit.opt, numpy as np
    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> opt = dr.opt.Adam(lr=0.1); opt["x"] = mi.TensorXf(np.zeros((3, 2), np.float32))
    >>> value, promoted, lr, (t, m, v, v_max) = opt.state["x"]
    >>> opt.state["x"] = (value, promoted, lr, (mi.UInt32(5), mi.Float([1, 1, 2, 2, 3, 3]), v, v_max))
    >>> before = opt.state["x"]; opt["x"] = mi.TensorXf(np.zeros((2, 2), np.float32))
    >>> carry_rows(opt, "x", before, np.array([2, -1]))
    >>> opt.state["x"][3][0], opt.state["x"][3][1]
    ([5], [3, 3, 0, 0])
    """
    import numpy as np

    extra = before[3]
    if not (isinstance(extra, tuple) and len(extra) == 4):
        return
    value, promoted, lr, _ = opt.state[key]
    width = max(1, dr.width(value.array) // max(len(sources), 1))
    rows = np.asarray(sources, np.int64)
    UInt32 = dr.uint32_array_t(type(value.array))
    index = UInt32((np.maximum(rows, 0)[:, None] * width + np.arange(width)[None]).ravel().astype(np.uint32))
    keep = dr.mask_t(type(value.array))(np.repeat(rows >= 0, width))

    def carried(old):
        return None if old is None else dr.gather(type(value.array), old, index, keep)

    t, m, v, v_max = extra
    opt.state[key] = (value, promoted, lr, (t, carried(m), carried(v), carried(v_max)))
