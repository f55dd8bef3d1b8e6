"""The training loop: steps of the model's protocol with Adam, until the step budget is spent.

Each step: the learning rate of the step (:func:`mitsnerf.train.schedule.learning_rate`, times the
model's per-parameter factors), the step's loss (:func:`mitsnerf.train.step.step_loss`, random
numbers from :func:`mitsnerf.train.schedule.step_rng`), a NaN check, ``opt.step()``, the new
values back into the model, and the values the model's :meth:`~mitsnerf.methods.base.Model.after_step`
returns written into the optimiser. Every ``log_every`` steps a history entry (``step``,
``seconds``, ``lr`` (the step's global learning rate), ``loss``, ``loss_mean`` of the interval,
``psnr`` of the last batch) and the
``on_log`` hook, whose time the clock does not count (it may evaluate the model).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import drjit as dr
import drjit.opt  # noqa: F401  (makes dr.opt available)

from mitsnerf.errors import MethodError, TrainingError, signal_cause
from mitsnerf.methods.base import ChoosesOptimizer, Model
from mitsnerf.train.checkpointing import CheckpointPolicy, stop_signals
from mitsnerf.train.clock import Clock
from mitsnerf.train.config import TrainConfig
from mitsnerf.train.data import PixelData
from mitsnerf.train.monitor import LossMonitor
from mitsnerf.train.progress import Progress
from mitsnerf.train.schedule import step_rng
from mitsnerf.train.step import apply_step, set_step_learning_rate, step_loss


@dataclass
class TrainState:
    """Where a run stands: what a checkpoint holds and a resumed run continues from."""

    opt: Any
    step: int = 0
    elapsed: float = 0.0
    """Training seconds spent so far (evaluation excluded)."""
    history: list = field(default_factory=list)
    monitor: dict = field(default_factory=dict)
    """:meth:`mitsnerf.train.monitor.LossMonitor.state`."""
    extra: dict = field(default_factory=dict)
    """The model's :meth:`~mitsnerf.methods.base.Model.extra_state` at this step (Dr.Jit values
    are references: the model replaces, never mutates, its state arrays)."""


@dataclass
class TrainResult:
    steps: int
    """Steps completed in all (a resumed run counts the earlier ones)."""
    seconds: float
    rays_per_s: float | None
    """Over the steps run in this session (None when none ran: a resumed run that only evaluates)."""
    samples_per_s: float | None
    final_loss: float
    history: list[dict] = field(default_factory=list)
    stopped_by: str = "steps"
    """``"steps"`` (the budget was spent) or ``"seconds"`` (the optional wall-clock cap)."""
    steps_run: int = 0
    """Steps run in this session."""


def make_optimizer(model: Model, base_lr: float):
    """An Adam optimiser holding every parameter of ``model``, or the model's own optimiser where it builds one
    (:class:`~mitsnerf.methods.base.ChoosesOptimizer`)."""
    opt = model.optimizer(base_lr) if isinstance(model, ChoosesOptimizer) else dr.opt.Adam(lr=base_lr)
    opt.update(model.parameters())
    return opt


def check_differentiable(model: Model, loss, step: int) -> None:
    """Raise :class:`~mitsnerf.errors.MethodError` naming ``model``'s class if its step's ``loss`` depends on none
    of its parameters (a method that renders from copies of them: there is no gradient to step)."""
    if not dr.grad_enabled(loss):
        raise MethodError(f"{type(model).__module__}.{type(model).__qualname__}", f"step {step}",
                          "the loss depends on none of parameters(), so there is nothing to step: render from the "
                          "values that set_parameters() receives (the optimiser's), not from copies of them")


class _Loop:
    def __init__(self, model: Model, data: PixelData, config: TrainConfig, base_lr: float, state: TrainState,
                 policy: CheckpointPolicy, on_log: Callable[[dict], None] | None) -> None:
        self.model, self.data, self.config, self.base_lr = model, data, config, base_lr
        self.opt, self.step, self.history = state.opt, state.step, list(state.history)
        self.policy, self.on_log = policy, on_log
        self.clock = Clock(state.elapsed)
        self.monitor = LossMonitor(config.divergence_factor, config.divergence_patience)
        self.monitor.load_state(state.monitor)
        self.snapshot = self.state()
        self.start_step, self.rays, self.loss, self.lr = state.step, 0, math.nan, base_lr

    def state(self) -> TrainState:
        from mitsnerf.train.checkpoint import optimizer_snapshot

        return TrainState(optimizer_snapshot(self.opt), self.step, self.clock.seconds(), list(self.history),
                          self.monitor.state(), dict(self.model.extra_state()))

    def save(self, state: TrainState) -> int:
        self.policy.checkpointer.save(state)
        return state.step

    def one_step(self) -> None:
        model, opt, config, step = self.model, self.opt, self.config, self.step
        lr = set_step_learning_rate(model, opt, self.base_lr, step, config)
        if step > 0 and model.objective_stage(step) != model.objective_stage(step - 1):
            self.monitor.restart()
        out = step_loss(model, self.data, config, step, step_rng(config.seed, step))
        check_differentiable(model, out.loss, step)
        dr.backward(out.loss)
        loss = float(out.loss[0])
        if not math.isfinite(loss):
            kept = "the initial parameters kept (before the first step)" if step == 0 else \
                f"parameters of step {step - 1} kept"
            raise TrainingError(None, f"step {step}", f"loss became {loss}; stopped, {kept}; {self.policy.where()}")
        apply_step(model, opt, step)
        self.step, self.rays, self.loss, self.lr = step + 1, self.rays + out.rays, loss, lr
        self.monitor.add(loss)
        entry = (
            self.log_entry(loss, out.mse) if self.step % config.log_every == 0 or self.step == config.steps else None
        )
        self.snapshot = self.state()
        if entry is not None and self.on_log is not None:
            with self.clock.paused():
                self.on_log(entry)
        if self.policy.due(self.step, self.monitor.healthy(loss)):
            self.save(self.snapshot)

    def log_entry(self, loss: float, mse) -> dict:
        """The history entry of this step; raises on a diverging loss."""
        entry = {"step": self.step, "seconds": self.clock.seconds(), "lr": self.lr, "loss": loss,
                 "loss_mean": self.monitor.close_interval(), "psnr": -10.0 * math.log10(max(float(mse[0]), 1e-12))}
        self.history.append(entry)
        if self.monitor.diverging:
            c = self.config
            raise TrainingError(None, f"step {self.step}",
                                f"loss diverging: the median loss of the last {c.divergence_patience} log intervals "
                                f"stayed above {c.divergence_factor:g} x its minimum {self.monitor.best:.3g} (now "
                                f"{self.monitor.last_median:.3g}); stopped; {self.policy.where()}")
        return entry

    def out_of_time(self) -> bool:
        return bool(self.config.seconds) and self.clock.seconds() >= self.config.seconds

    def result(self, seconds_of_steps: float) -> TrainResult:
        ran = self.step - self.start_step
        rate = self.rays / seconds_of_steps if ran and seconds_of_steps > 0 else None
        samples = None if rate is None else rate * max(self.model.samples_per_ray(), 1)
        return TrainResult(self.step, self.clock.seconds(), rate, samples, self.loss, self.history,
                           "seconds" if self.step < self.config.steps else "steps", ran)


def train(model: Model, data: PixelData, config: TrainConfig, base_lr: float, *, state: TrainState | None = None,
          progress: bool = True, on_log: Callable[[dict], None] | None = None,
          checkpointer=None) -> tuple[TrainResult, Any]:
    """Optimise ``model`` on ``data`` for ``config.steps`` steps; returns (result, optimiser).

    ``state`` continues an earlier run (a checkpoint's). ``checkpointer``
    (:class:`mitsnerf.train.checkpoint.Checkpointer`) writes the state every ``checkpoint_every``
    steps while healthy, at the end, and when interrupted (SIGINT, SIGTERM, SIGHUP: then
    :class:`mitsnerf.errors.Interrupted` is raised with the continue-with message).

    Raises :class:`mitsnerf.errors.TrainingError` naming the step on a non-finite loss
    (checked before the optimiser step: the model keeps the previous step's parameters) or a
    diverging one (:class:`mitsnerf.train.monitor.LossMonitor`).
    """
    loop = _Loop(model, data, config, base_lr, state or TrainState(make_optimizer(model, base_lr)),
                 CheckpointPolicy(checkpointer, config.checkpoint_every), on_log)
    model.set_parameters(loop.opt)
    bar = Progress(getattr(model, "name", None) or type(model).__name__, config.steps, loop.step, progress)
    t0 = loop.clock.seconds()
    try:
        with stop_signals():  # up to the last checkpoint: a signal while the bar closes or the file is written too
            try:
                while loop.step < config.steps and not loop.out_of_time():
                    loop.one_step()
                    bar.step()
                    if loop.history and loop.history[-1]["step"] == loop.step:
                        bar.show(loop.history[-1])
            finally:
                bar.close()
            result = loop.result(loop.clock.seconds() - t0)
            if checkpointer is not None:
                loop.save(loop.state())
    except BaseException as exc:  # a signal, also one a library turned into another error
        stop = signal_cause(exc)
        if stop is None:
            raise
        raise loop.policy.interrupted(stop, lambda: loop.save(loop.snapshot)) from None
    return result, loop.opt
