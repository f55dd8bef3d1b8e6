"""Training checkpoints: parameters, Adam state, step, history and config in one atomic file.

A run directory holds at most one checkpoint, ``RUN/checkpoint.npz``, replaced atomically
(:func:`mitsnerf.data.atomic.atomic_write_bytes`) each time, so it is always a complete,
loadable file. It is a numpy ``.npz`` (read with ``allow_pickle=False``)::

    meta.json              uint8 bytes of a JSON object (below)
    param/<name>           float32 parameter values, the model's shapes
    adam/<name>/m          Adam first-moment EMA (flat, as drjit.opt keeps it)
    adam/<name>/v          Adam second-moment EMA (flat)
    adam/<name>/v_max      AMSGrad maximum (only when amsgrad is on)
    extra/<name>           the model's ``extra_state()`` arrays

    meta.json = {"format": 2, "step": k, "elapsed": seconds, "config": run config,
                 "history": [...], "monitor": loss-monitor state, "optimizer": {"type": "Adam",
                 "lr": ..., "beta_1": ..., "params": {name: {"t": Adam step count,
                 "lr": per-parameter lr or null, "promoted": bool}}}, "rng": "..."}

What makes a resume bit-for-bit: the trainer draws step ``k``'s random numbers from a
generator seeded by ``(seed, k)`` alone (:func:`mitsnerf.train.step_rng`), so the RNG state
*is* the step; the parameters and every Adam moment are stored as the exact float32 bits;
Adam's step count ``t`` is restored as an evaluated (opaque) UInt32 exactly as
``drjit.opt.Adam.step`` leaves it; the learning rate is recomputed from the step by the
schedule; the loss monitor's interval losses are stored, so the resumed history is the
uninterrupted one's.

The gradients must also be summed in the same order every run. ``nerf``'s are, with any
thread count: its layers add their biases through :func:`mitsnerf.fields.nerf.linear`, whose
bias gradient is a block sum; ``drjit.nn.Linear``'s own broadcast adjoint is a multi-threaded
scatter-add whose rounding follows the thread scheduling, and it made a resumed nerf run
differ from the straight one by 1 ulp in about one run of three. The grid methods (``voxel``,
``ngp``, ``mitsuba-inverse``) still accumulate their grid gradients by multi-threaded scatter-adds
(the adjoint of their interpolated grid lookups): they resume bit-for-bit single-threaded
(``drjit.set_thread_count(1)``); multi-threaded, any two runs of them, resumed or not, differ
in the last bits after a step and drift apart slowly from there (~1e-6 after 20 steps). All of this is
the LLVM backend's: on CUDA the scatter-adds are float atomics that no thread count orders, so a resume
there continues the run to round-off, not bit for bit (:mod:`mitsnerf.train.threads`).

>>> import tempfile, mitsuba as mi, drjit as dr, drjit.opt
>>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
>>> opt = dr.opt.Adam(lr=0.1); opt["x"] = mi.TensorXf(np.ones((2, 2), np.float32))
>>> path = Path(tempfile.mkdtemp()) / CHECKPOINT_FILE
>>> save_checkpoint(path, capture(3, opt, config={"method": "demo"}))
>>> ckpt = load_checkpoint(path)
>>> ckpt.step, ckpt.params["x"].shape, ckpt.optimizer["params"]["x"]["t"]
(3, (2, 2), 0)
"""

from __future__ import annotations

import io
import json
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mitsnerf.data.arrays import read_npz
from mitsnerf.data.atomic import atomic_write_bytes
from mitsnerf.errors import CLI, DatasetError, DiskFullError, Words

CHECKPOINT_FILE = "checkpoint.npz"
FORMAT_VERSION = 2
#: The largest step a checkpoint may hold: :class:`mitsnerf.train.TrainConfig`'s largest ``steps``.
MAX_STEP = 10**8
_ADAM_HYPER = ("beta_1", "beta_2", "epsilon", "mask_updates", "promote_fp16", "uniform", "amsgrad")


def _numpy(value) -> np.ndarray:
    return np.array(value.numpy() if hasattr(value, "numpy") else value)


@dataclass
class Checkpoint:
    """A training state in numpy form (what :func:`save_checkpoint` writes)."""

    step: int
    """Optimiser steps completed."""
    elapsed: float
    """Training seconds spent before this point (for a ``seconds`` budget)."""
    config: dict
    """The run configuration: method, method_config, train, dataset (plain JSON)."""
    params: dict[str, np.ndarray]
    optimizer: dict
    """Type, hyperparameters, per-parameter ``t``/``lr``/``promoted``; moments under ``moments``."""
    history: list = field(default_factory=list)
    monitor: dict = field(default_factory=dict)
    """The trainer's loss-monitor state (:class:`mitsnerf.train.monitor.LossMonitor`)."""
    extra_state: dict[str, np.ndarray] = field(default_factory=dict)
    moments: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    """Per parameter ``{"m": ..., "v": ...[, "v_max": ...]}``."""


def optimizer_snapshot(opt) -> dict:
    """A reference copy of ``opt.state`` (no data copied).

    ``drjit.opt`` replaces each state tuple on every step rather than mutating it, so the
    snapshot keeps the values of the moment it was taken; :func:`capture` turns it into a
    checkpoint later (e.g. after a Ctrl-C in the middle of the next step).
    """
    return {"state": dict(opt.state), "lr": opt.lr, "opt": opt}


def capture(
    step: int,
    opt_or_snapshot,
    *,
    config: Mapping[str, Any] | None = None,
    elapsed: float = 0.0,
    history: list | None = None,
    monitor: Mapping[str, Any] | None = None,
    extra_state: Mapping[str, Any] | None = None,
) -> Checkpoint:
    """The numpy :class:`Checkpoint` of an Adam optimiser (or an :func:`optimizer_snapshot` of one)."""
    import drjit as dr
    import drjit.opt  # noqa: F401

    snap = opt_or_snapshot if isinstance(opt_or_snapshot, dict) else optimizer_snapshot(opt_or_snapshot)
    opt = snap["opt"]
    if not isinstance(opt, dr.opt.Adam):
        raise TypeError(f"checkpoints store Adam optimisers (drjit.opt.Adam/AdamW), got {type(opt).__name__}")
    lr = snap["lr"]
    optim: dict[str, Any] = {
        "type": type(opt).__name__,
        "lr": float(lr) if isinstance(lr, (int, float)) else None,
        **{k: getattr(opt, k) for k in _ADAM_HYPER},
        "params": {},
    }
    params: dict[str, np.ndarray] = {}
    moments: dict[str, dict[str, np.ndarray]] = {}
    for key, (value, promoted, p_lr, extra) in snap["state"].items():
        t, m, v, v_max = extra
        params[key] = _numpy(value)
        moments[key] = {"m": _numpy(m), "v": _numpy(v)}
        if v_max is not None:
            moments[key]["v_max"] = _numpy(v_max)
        optim["params"][key] = {
            "t": int(_numpy(t).reshape(-1)[0]),
            "lr": float(p_lr) if isinstance(p_lr, (int, float)) else None,
            "promoted": bool(promoted),
        }
    return Checkpoint(
        step=int(step),
        elapsed=float(elapsed),
        config=dict(config or {}),
        params=params,
        optimizer=optim,
        history=list(history or []),
        monitor=dict(monitor or {}),
        extra_state={k: np.asarray(_numpy(v)) for k, v in (extra_state or {}).items()},
        moments=moments,
    )


def save_checkpoint(path: str | os.PathLike, ckpt: Checkpoint) -> None:
    """Write ``ckpt`` to ``path`` atomically (complete file or the previous one, never half)."""
    meta = {
        "format": FORMAT_VERSION,
        "step": ckpt.step,
        "elapsed": ckpt.elapsed,
        "config": ckpt.config,
        "history": ckpt.history,
        "monitor": ckpt.monitor,
        "optimizer": ckpt.optimizer,
        "rng": "step k draws from mitsnerf.train.step_rng(train.seed, k): the generator state is the step",
    }
    arrays: dict[str, Any] = {"meta.json": np.frombuffer(json.dumps(meta).encode("utf-8"), dtype=np.uint8)}
    for key, value in ckpt.params.items():
        arrays[f"param/{key}"] = value
    for key, moms in ckpt.moments.items():
        for name, value in moms.items():
            arrays[f"adam/{key}/{name}"] = value
    for key, value in ckpt.extra_state.items():
        arrays[f"extra/{key}"] = value
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, buf.getvalue())


def load_checkpoint(path: str | os.PathLike) -> Checkpoint:
    """Read a checkpoint; :class:`~mitsnerf.errors.DatasetError` naming the file if it is not one."""
    path = Path(path)
    if not path.exists():
        raise DatasetError(path, None, "no checkpoint here (train with --out to write one)")
    files = read_npz(path, "checkpoint")
    if "meta.json" not in files:
        raise DatasetError(path, "meta.json", "missing: not a mitsnerf checkpoint")
    try:
        meta = json.loads(files.pop("meta.json").tobytes().decode("utf-8"))
    except ValueError as exc:  # UnicodeDecodeError and JSONDecodeError are ValueErrors
        raise DatasetError(path, "meta.json", f"not JSON ({exc}): not a mitsnerf checkpoint") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT_VERSION:
        got = meta.get("format") if isinstance(meta, dict) else meta
        raise DatasetError(path, "format", f"expected {FORMAT_VERSION}, got {got!r}")
    missing = [k for k in ("step", "elapsed", "optimizer") if k not in meta]
    if missing:
        raise DatasetError(path, "meta.json", f"missing {', '.join(missing)}: not a complete mitsnerf checkpoint")
    _check_counts(meta, path)
    params: dict[str, np.ndarray] = {}
    extra: dict[str, np.ndarray] = {}
    moments: dict[str, dict[str, np.ndarray]] = {}
    for name, value in files.items():
        kind, _, rest = name.partition("/")
        if kind == "param":
            params[rest] = value
        elif kind == "extra":
            extra[rest] = value
        elif kind == "adam":
            key, _, moment = rest.rpartition("/")
            moments.setdefault(key, {})[moment] = value
    return Checkpoint(
        step=int(meta["step"]),
        elapsed=float(meta["elapsed"]),
        config=meta.get("config") or {},
        params=params,
        optimizer=meta["optimizer"],
        history=meta.get("history") or [],
        monitor=meta.get("monitor") or {},
        extra_state=extra,
        moments=moments,
    )


def _check_counts(meta: Mapping[str, Any], path: Path) -> None:
    """Refuse a ``step`` that is not a whole number in ``[0, MAX_STEP]`` or an ``elapsed`` that is not a
    finite number of seconds >= 0 (a checkpoint edited by hand or written by something else)."""
    step, elapsed = meta["step"], meta["elapsed"]
    if isinstance(step, bool) or not isinstance(step, int) or not 0 <= step <= MAX_STEP:
        raise DatasetError(path, "step", f"must be a whole number of steps in [0, {MAX_STEP}], got {step!r}")
    if isinstance(elapsed, bool) or not isinstance(elapsed, (int, float)) or not 0 <= elapsed < float("inf"):
        raise DatasetError(path, "elapsed", f"must be a finite number of seconds >= 0, got {elapsed!r}")


def _like(reference, values: np.ndarray):
    """``values`` as a Dr.Jit value of ``reference``'s type (its shape may differ)."""
    tp = type(reference)
    return tp(np.ascontiguousarray(values))


def restore_optimizer(opt, ckpt: Checkpoint, where: str | os.PathLike | None = None) -> None:
    """Put the checkpoint's parameters and Adam state into ``opt`` (already holding the same keys).

    A parameter whose shape changed during training (a coarse-to-fine grid) takes the
    checkpoint's shape. Raises :class:`~mitsnerf.errors.DatasetError` if the keys or the
    optimiser's hyperparameters differ from the checkpoint's.
    """
    import drjit as dr

    info = ckpt.optimizer
    if info.get("type") != type(opt).__name__:
        raise DatasetError(
            where, "optimizer.type", f"checkpoint has {info.get('type')}, the run uses {type(opt).__name__}"
        )
    for name in _ADAM_HYPER:
        if name in info and info[name] != getattr(opt, name):
            raise DatasetError(
                where, f"optimizer.{name}", f"checkpoint has {info[name]!r}, the run uses {getattr(opt, name)!r}"
            )
    saved, current = set(info["params"]), set(opt.keys())
    if saved != current:
        raise DatasetError(where, "params", f"checkpoint holds {sorted(saved)}, the model has {sorted(current)}")
    lost = sorted(k for k in saved if k not in ckpt.params or not {"m", "v"} <= set(ckpt.moments.get(k, {})))
    if lost:
        raise DatasetError(where, "param/" + lost[0], "missing from the checkpoint (its parameter or Adam moments): "
                                                      f"{len(lost)} of {len(saved)} parameters incomplete")
    if info.get("lr") is not None:
        opt.set_learning_rate(float(info["lr"]))
    for key, entry in info["params"].items():
        opt[key] = _like(opt[key], ckpt.params[key])
        value, _, _, _ = opt.state[key]
        Leaf = type(value.array)
        moms = ckpt.moments.get(key, {})
        t = dr.opaque(dr.uint32_array_t(Leaf), int(entry["t"]))
        m, v = Leaf(moms["m"]), Leaf(moms["v"])
        v_max = Leaf(moms["v_max"]) if "v_max" in moms else None
        if getattr(opt, "amsgrad", False) and v_max is None:
            v_max = dr.opaque(Leaf, 0, dr.width(value.array))
        opt.state[key] = (value, bool(entry["promoted"]), entry["lr"], (t, m, v, v_max))


class Checkpointer:
    """Writes a run's checkpoint where the trainer says (:func:`mitsnerf.train.train`: every
    ``checkpoint_every`` steps, at the end, when interrupted).

    ``config`` is stored with each checkpoint (what ``train --resume`` rebuilds the run from); ``words``: how
    its messages say to continue (:data:`~mitsnerf.errors.CLI`: ``mitsnerf train --resume --out RUN``,
    :data:`~mitsnerf.errors.API`: ``api.fit(resume=True, out='RUN')``).
    """

    def __init__(self, path: str | os.PathLike, config: Mapping[str, Any] | None = None, words: Words = CLI) -> None:
        self.path = Path(path)
        self.config = dict(config or {})
        self.words = words
        self.last_step: int | None = None

    def save(self, state) -> None:
        """Write a :class:`mitsnerf.train.TrainState` (its optimiser may be a snapshot). A full disk is a
        :class:`~mitsnerf.errors.DiskFullError` saying which checkpoint is kept and how to continue."""
        history = [h for h in state.history if h.get("step", 0) <= state.step]
        ckpt = capture(state.step, state.opt, config=self.config, elapsed=state.elapsed, history=history,
                       monitor=state.monitor, extra_state=state.extra)
        try:
            save_checkpoint(self.path, ckpt)
        except DiskFullError as exc:
            raise DiskFullError(self.path, exc.reason, f"step {state.step} was not saved; {self.kept()}") from exc
        self.last_step = int(state.step)

    def kept(self) -> str:
        """What a failed write leaves, and how to go on: ``the last checkpoint, step k, is kept; ...``."""
        if self.last_step is None and not self.path.is_file():
            return "no checkpoint was written; free space and train again"
        which = f"step {self.last_step}" if self.last_step is not None else "from before this session"
        return (f"the last checkpoint, {which}, is kept; free space, then continue with "
                f"{self.words.command('train', resume=True, out=self.path.parent)}")

    def describe(self) -> str:
        """``"last good checkpoint: PATH (step k)"`` for messages, or what exists on disk."""
        if self.last_step is not None:
            return f"last good checkpoint: {self.path} (step {self.last_step})"
        if self.path.is_file():
            return f"last good checkpoint: {self.path} (from before this session)"
        return "no checkpoint written"
