"""The training loop: random ray batches over all training pixels, Adam, progress, checkpoints,
NaN and divergence checks.

Each step draws ``batch_rays`` pixels uniformly from every training view, renders
them with the model (jittered stratified samples), and minimises the mean squared
error on linear RGB (plus the model's own regularisers) with ``drjit.opt.Adam``.
Random numbers of step ``k`` come from a generator seeded with ``(seed, k)`` alone,
so a run resumed at step ``k`` draws exactly what an uninterrupted run would. Whether it
then also computes the same bits depends on the method summing its gradients in a fixed
order (``nerf`` does; the grid methods only single-threaded): see :mod:`mitsnerf.checkpoint`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import drjit as dr
import drjit.opt  # noqa: F401  (makes dr.opt available)
import mitsuba as mi
import numpy as np

from mitsnerf.errors import TrainingError
from mitsnerf.math.camera import Camera
from mitsnerf.methods.base import Model
from mitsnerf.render.rays import RayBatch, camera_rays, to_array3f


@dataclass(frozen=True)
class TrainConfig:
    """How long and how to train (the method's own settings live in its config)."""

    steps: int = 3000
    """Maximum optimiser steps."""
    seconds: float = 0.0
    """Wall-clock budget in seconds (0: none); training stops at whichever limit comes first."""
    batch_rays: int = 2048
    """Rays per step."""
    lr: float = 0.0
    """Adam learning rate (0: the method's default)."""
    lr_final_factor: float = 0.1
    """Exponential decay of the learning rate to lr * factor at the end of the budget."""
    seed: int = 0
    log_every: int = 25
    """Steps between progress-bar updates and history entries."""
    checkpoint_every: int = 0
    """Steps between checkpoints (0: only at the end and on Ctrl-C); needs a run directory."""
    divergence_factor: float = 10.0
    """Diverging: the mean loss of a log interval above this times its running minimum (0: no check)."""
    divergence_patience: int = 3
    """Log intervals in a row above ``divergence_factor`` x minimum before training stops."""

    def __post_init__(self) -> None:
        if self.steps < 1:
            raise ValueError(f"steps: must be >= 1, got {self.steps}")
        if self.seconds < 0:
            raise ValueError(f"seconds: must be >= 0, got {self.seconds}")
        if self.batch_rays < 1:
            raise ValueError(f"batch_rays: must be >= 1, got {self.batch_rays}")
        if self.lr < 0:
            raise ValueError(f"lr: must be >= 0, got {self.lr}")
        if not 0 < self.lr_final_factor <= 1:
            raise ValueError(f"lr_final_factor: must be in (0, 1], got {self.lr_final_factor}")
        if self.log_every < 1:
            raise ValueError(f"log_every: must be >= 1, got {self.log_every}")
        if self.checkpoint_every < 0:
            raise ValueError(f"checkpoint_every: must be >= 0, got {self.checkpoint_every}")
        if self.divergence_factor != 0 and not self.divergence_factor > 1:
            raise ValueError(f"divergence_factor: must be 0 (off) or > 1, got {self.divergence_factor}")
        if self.divergence_patience < 1:
            raise ValueError(f"divergence_patience: must be >= 1, got {self.divergence_patience}")


@dataclass(frozen=True)
class PixelData:
    """Every training pixel as a ray and a target colour (Dr.Jit arrays of width P)."""

    rays: RayBatch
    rgb: Any  # Array3f (P,)
    images: np.ndarray | None = None
    """The views themselves, (V, H, W, 3) linear RGB, for methods that render whole cameras."""
    cameras: tuple[Camera, ...] = ()
    pixel_center: float = 0.5

    @classmethod
    def from_views(cls, images: np.ndarray, cameras: Sequence[Camera], pixel_center: float = 0.5) -> "PixelData":
        """``images`` (V, H, W, 3) linear RGB with one camera each."""
        if len(images) != len(cameras):
            raise ValueError(f"{len(images)} images but {len(cameras)} cameras")
        rays = camera_rays(mi.Array3f, cameras, pixel_center)
        return cls(rays, to_array3f(mi.Array3f, images.reshape(-1, 3)), images, tuple(cameras), pixel_center)

    @property
    def size(self) -> int:
        return self.rays.size


@dataclass
class TrainResult:
    steps: int
    seconds: float
    rays_per_s: float
    samples_per_s: float
    final_loss: float
    history: list[dict] = field(default_factory=list)
    """One entry per ``log_every`` steps: step, seconds, loss (of the last step), loss_mean (of
    the interval), psnr (of the last batch); a resumed run's history includes the earlier entries."""


def step_rng(seed: int, step: int):
    """The generator of step ``step``: a pure function of ``(seed, step)``."""
    return dr.rng(seed=(int(seed) & 0xFFFFFFFF) << 32 | (int(step) & 0xFFFFFFFF))


def learning_rate(config: TrainConfig, base_lr: float, progress: float) -> float:
    """Exponential decay from ``base_lr`` to ``base_lr * lr_final_factor`` as progress goes 0 -> 1.

    >>> learning_rate(TrainConfig(lr_final_factor=0.1), 1.0, 0.5)  # doctest: +ELLIPSIS
    0.3162...
    """
    return base_lr * config.lr_final_factor ** min(max(progress, 0.0), 1.0)


def make_optimizer(model: Model, lr: float):
    opt = dr.opt.Adam(lr=lr)
    for key, value in model.parameters().items():
        opt[key] = value
    return opt


def train(
    model: Model,
    data: PixelData,
    config: TrainConfig,
    base_lr: float,
    *,
    opt=None,
    start_step: int = 0,
    elapsed: float = 0.0,
    history: list[dict] | None = None,
    progress: bool = True,
    on_log: Callable[[dict], None] | None = None,
    should_stop: Callable[[int], bool] | None = None,
    checkpointer=None,
) -> tuple[TrainResult, Any]:
    """Optimise ``model`` on ``data``; returns (result, optimiser).

    ``opt``/``start_step``/``elapsed``/``history`` continue an earlier run (checkpoint
    resume, :func:`mitsnerf.checkpoint.restore_optimizer`). Each step is the model's own
    (:meth:`Model.training_loss`) when it supplies one, else a random ray batch through
    ``render_rays``; the scheduled learning rate is multiplied per parameter by
    :meth:`Model.lr_scales`.

    ``on_log(entry)`` runs after each history entry; it may add keys to ``entry`` (they stay
    in the history), and the time it takes is kept off the training clock (the ``seconds``
    budget, the logged and returned seconds, rays/s), so it may evaluate the model.

    ``checkpointer`` (a :class:`mitsnerf.checkpoint.Checkpointer`) writes the state after
    every ``config.checkpoint_every`` steps (skipped while the loss looks diverging, so the
    file left is the last good one), at the end, and on ``KeyboardInterrupt``: then the
    state after the last *completed* step is written and the interrupt re-raised, its
    message saying where the checkpoint is.

    Raises :class:`mitsnerf.errors.TrainingError` naming the step when

    - the loss is not finite (checked before the optimiser step: the model keeps the
      parameters of the previous step, the checkpoint on disk is untouched);
    - the loss diverges: the mean loss of a log interval exceeds ``divergence_factor``
      times the lowest interval mean so far for ``divergence_patience`` intervals in a row.
    """
    from tqdm.auto import tqdm

    from mitsnerf.checkpoint import optimizer_snapshot

    opt = opt if opt is not None else make_optimizer(model, base_lr)
    model.set_parameters(opt)
    Float, UInt32 = mi.Float, mi.UInt32
    n_jitter = model.jitter_size()
    history = list(history or [])
    start = time.perf_counter() - elapsed
    # A time budget shows seconds done out of the budget (steps may never reach their limit).
    timed = config.seconds > 0
    bar = tqdm(total=config.seconds if timed else config.steps, initial=min(elapsed, config.seconds) if timed else start_step,
               disable=not progress, desc=f"train {model.name}", unit="s" if timed else "step", dynamic_ncols=True,
               leave=False, bar_format="{l_bar}{bar}| {n:.0f}/{total:.0f} s [{postfix}]" if timed else None)
    step = start_step
    loss_value = float("nan")
    rays_done = 0
    t_loop = time.perf_counter()
    snap, snap_step = optimizer_snapshot(opt), step
    factor, best, bad = config.divergence_factor, math.inf, 0
    interval_sum, interval_n = 0.0, 0

    def where() -> str:
        return checkpointer.describe() if checkpointer is not None else "no checkpoint (no run directory)"

    try:
        while step < config.steps:
            now = time.perf_counter() - start
            if config.seconds and now >= config.seconds:
                break
            if should_stop is not None and should_stop(step):
                break
            frac = step / config.steps
            if config.seconds:
                frac = max(frac, now / config.seconds)
            lr = learning_rate(config, base_lr, frac)
            opt.set_learning_rate(lr)
            scales = model.lr_scales(step)
            if scales:
                opt.set_learning_rate({k: lr * float(f) for k, f in scales.items() if k in opt})

            rng = step_rng(config.seed, step)
            own = model.training_loss(data, step, rng)
            if own is None:
                B = config.batch_rays
                idx = dr.minimum(UInt32(rng.random(Float, B) * data.size), data.size - 1)
                batch = data.rays.take(idx)
                target = dr.gather(mi.Array3f, data.rgb, idx)
                u = rng.random(Float, B * n_jitter) if n_jitter else None

                out = model.render_rays(batch.o, batch.d, u=u, training=True)
                mse = dr.mean(dr.square(out.rgb - target), axis=None)
                loss = mse
                for extra in (out.extra_losses or {}).values():
                    loss = loss + extra
                for aux in (out.aux_rgb or {}).values():
                    loss = loss + dr.mean(dr.square(aux - target), axis=None)
            else:
                B, loss, mse = own.rays, own.loss, own.mse
            dr.backward(loss)
            loss_value = float(loss[0])
            if not math.isfinite(loss_value):
                raise TrainingError(None, f"step {step}", f"loss became {loss_value}; stopped, parameters of step {step - 1} kept; {where()}")
            opt.step()
            model.set_parameters(opt)
            model.on_step(step, opt)
            step += 1
            snap, snap_step = optimizer_snapshot(opt), step
            rays_done += B
            bar.update(min(time.perf_counter() - start, config.seconds) - bar.n if timed else 1)
            interval_sum, interval_n = interval_sum + loss_value, interval_n + 1
            if step % config.log_every == 0 or step == config.steps:
                mse_value = float(mse[0])
                mean = interval_sum / interval_n
                interval_sum, interval_n = 0.0, 0
                entry = {
                    "step": step,
                    "seconds": time.perf_counter() - start,
                    "loss": loss_value,
                    "loss_mean": mean,
                    "psnr": -10.0 * math.log10(max(mse_value, 1e-12)),
                }
                history.append(entry)
                bar.set_postfix(step=step, loss=f"{loss_value:.2e}", psnr=f"{entry['psnr']:.2f}")
                if factor:
                    bad = bad + 1 if mean > factor * best else 0
                    best = min(best, mean)
                    if bad >= config.divergence_patience:
                        raise TrainingError(
                            None, f"step {step}",
                            f"loss diverging: the mean loss of the last {config.divergence_patience} log intervals "
                            f"stayed above {factor:g} x its minimum {best:.3g} (now {mean:.3g}); stopped; {where()}",
                        )
                if on_log is not None:
                    paused = time.perf_counter()
                    on_log(entry)
                    paused = time.perf_counter() - paused  # the hook's time is not training time
                    start += paused
                    t_loop += paused
            healthy = not factor or (bad == 0 and loss_value <= factor * best)
            due = config.checkpoint_every and step % config.checkpoint_every == 0
            if checkpointer is not None and due and healthy:
                checkpointer.save(step, snap, time.perf_counter() - start, history)
    except KeyboardInterrupt:
        if checkpointer is None:
            raise
        checkpointer.save(snap_step, snap, time.perf_counter() - start, history)
        raise KeyboardInterrupt(
            f"checkpoint of step {snap_step} saved to {checkpointer.path}; continue with "
            f"mitsnerf train --resume --out {checkpointer.path.parent}"
        ) from None
    finally:
        bar.close()
    seconds = time.perf_counter() - start
    loop_seconds = max(time.perf_counter() - t_loop, 1e-9)
    if checkpointer is not None:
        checkpointer.save(step, opt, seconds, history)
    result = TrainResult(
        steps=step,
        seconds=seconds,
        rays_per_s=rays_done / loop_seconds,
        samples_per_s=rays_done * max(model.samples_per_ray(), 1) / loop_seconds,
        final_loss=loss_value,
        history=history,
    )
    return result, opt
