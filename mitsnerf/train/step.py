"""One training step's loss, by protocol: a random ray batch for per-ray models, the model's own for whole-view ones.

For a :class:`mitsnerf.methods.base.RendersRays` model (``B`` rays, targets ``C*``)::

    loss = mean_rays,channels (C - C*)^2 + sum extra_losses + sum_aux mean (C_aux - C*)^2
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from mitsnerf.methods.base import Model, RendersRays, StepLoss, TrainsOnViews
from mitsnerf.train.config import TrainConfig
from mitsnerf.train.data import PixelData


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
    """The step of ``model``'s capability (:class:`~mitsnerf.methods.base.RendersRays` or
    :class:`~mitsnerf.methods.base.TrainsOnViews`)."""
    if isinstance(model, RendersRays):
        return ray_batch_loss(model, data, config, rng)
    if isinstance(model, TrainsOnViews):
        return model.training_loss(data, step, rng)
    raise TypeError(f"{type(model).__name__}: a Model must render rays (RendersRays: subclass RayModel) or "
                    "train on views (TrainsOnViews: subclass ViewModel)")


def apply_step(model: Model, opt, step: int) -> None:
    """The optimiser's step and what follows it (methods/base.py): the optimiser's values handed to the model,
    then the values the model returns from ``after_step`` (resampled, clamped) written into the optimiser and
    handed back. ``opt``: a ``drjit.opt`` optimiser whose gradients are set."""
    opt.step()
    model.set_parameters(opt)
    new = model.after_step(step, opt)
    if new:
        opt.update(new)
        model.set_parameters(opt)
