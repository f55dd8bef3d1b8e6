"""The conformance suite: everything the harness promises for a method, run on the method's tiny configuration.

``mitsnerf methods --check NAME`` runs it on one registered method (a plugin author's first test);
``tests/methods/test_conformance.py`` runs it on every registered method. On a tiny generated dataset
(:data:`TINY_SCENE`), with the method's ``tiny`` settings, one thread (``--deterministic``; on CUDA, whose
float atomics no thread count orders, as it comes: :func:`mitsnerf.train.threads.nondeterminism`):

========================  ==================================================================================
promise                   checked
========================  ==================================================================================
builds, with parameters   the model of the tiny settings builds, and ``parameters()`` is a non-empty mapping
to train                  of Dr.Jit float arrays (:func:`mitsnerf.methods.check_model`)
trains and evaluates      a few steps train with a finite loss; every test view renders finite, of the view's
                          shape; the scores are finite; the run directory holds its files
SIGTERM checkpoints       a real SIGTERM at a logged step stops training with the checkpoint of that step
resume equals the run     the stopped run, resumed, ends with the same parameters as the run never stopped:
never stopped             bit for bit on LLVM; on CUDA to :data:`RESUME_ATOL`
renders a saved run       the run read back from its directory renders a test view as the run did
exports its density       (a queryable density only) ``export`` writes sigma_t, and the run has density scores
other settings refused    resuming with another ``lr`` is refused, naming ``method_config`` and ``lr``
========================  ==================================================================================

A failure names the promise it broke and what was seen; a promise whose prerequisite failed is not run.
The suite checks promises, not quality: it never trains the method's own (default) settings, and its report
says so.
"""

from __future__ import annotations

import os
import signal
import tempfile
import threading
import traceback
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mitsnerf.config import apply_overrides
from mitsnerf.errors import MethodError, MitsnerfError
from mitsnerf.train.threads import nondeterminism

#: The tiny scene the suite trains on (spec data): a 16^3 cloud seen by 3 + 2 cameras of 8 x 8 pixels, a few spp.
TINY_SCENE: Mapping[str, Any] = {
    "name": "tiny",
    "description": "a 16^3 cloud, 8x8 views",
    "volume": {"family": "cloud", "resolution": 16, "seed": 1, "sigma_t_scale": 30.0,
               "params": {"albedo": [0.8, 0.8, 0.8]}},
    "lights": [
        {"type": "constant", "radiance": [0.5, 0.55, 0.6]},
        {"type": "directional", "direction": [-0.4, -0.8, -0.45], "irradiance": [4.0, 3.8, 3.5]},
    ],
    "cameras": {"rig": "sphere", "n_train": 3, "n_test": 2, "width": 8, "height": 8, "fov": 40.0, "radius": 2.2,
                "seed": 0},
    "render": {"spp_train": 4, "spp_test": 8, "max_depth": -1, "seed": 0, "noise_floor": True},
}
#: Training steps of the suite's runs, and the step at which the interrupted one is stopped.
STEPS, STOP_AT = 6, 3
#: Rays per training step of the suite's runs.
BATCH_RAYS = 64


class Broken(AssertionError):
    """A promise not kept; the message says what was seen."""


class Skipped(Exception):
    """A promise that does not apply to the method, or cannot be checked here; the message says why."""


@dataclass(frozen=True)
class Outcome:
    """One promise's result: ``passed`` None when it was not run (a prerequisite failed, or it does not apply)."""

    promise: str
    passed: bool | None
    detail: str = ""


@dataclass(frozen=True)
class ConformanceReport:
    method: str
    outcomes: tuple[Outcome, ...]
    settings: Mapping[str, Any] = field(default_factory=dict)
    """The method settings the suite trained: the method's ``tiny`` ones (and the caller's overrides)."""

    @property
    def passed(self) -> bool:
        return all(o.passed is not False for o in self.outcomes)

    def failures(self) -> list[Outcome]:
        return [o for o in self.outcomes if o.passed is False]

    def summary(self) -> str:
        """One line per promise (``ok``, ``FAILED``, ``not run``) and the verdict."""
        word = {True: "ok", False: "FAILED", None: "not run"}
        lines = [f"{word[o.passed]:8s} {o.promise}" + (f": {o.detail}" if o.detail else "") for o in self.outcomes]
        verdict = "conforms" if self.passed else f"does not conform ({len(self.failures())} broken)"
        head = f"conformance of {self.method!r}, trained only at its tiny settings, not its defaults (a check of " \
               f"promises, not of quality):\n  {scope(self.settings)}"
        return "\n".join([head, *lines, f"{self.method}: {verdict}"])


def scope(settings: Mapping[str, Any]) -> str:
    """What the suite trains, for its report's head: ``settings`` (the method's ``tiny`` ones), steps and scene.

    >>> scope({"n_samples": 8, "network": {"width": 8}})
    'tiny settings n_samples=8, network.width=8; 6 steps of 64 rays on a 16^3 cloud in 3 views of 8 x 8 pixels'
    """
    given = ", ".join(f"{k}={v!r}" for k, v in _flat(settings)) or "(none: the defaults)"
    views = TINY_SCENE["cameras"]
    return (f"tiny settings {given}; {STEPS} steps of {BATCH_RAYS} rays on a {TINY_SCENE['volume']['resolution']}^3 "
            f"cloud in {views['n_train']} views of {views['width']} x {views['height']} pixels")


def _flat(settings: Mapping[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    """``(dotted key, value)`` of nested ``settings``."""
    out: list[tuple[str, Any]] = []
    for key, value in settings.items():
        if isinstance(value, Mapping):
            out += _flat(value, f"{prefix}{key}.")
        else:
            out.append((f"{prefix}{key}", value))
    return out


@dataclass
class _Context:
    method: str
    config: dict
    dataset: Any
    work: Path
    progress: bool
    runs: dict = field(default_factory=dict)

    def fit(self, out: str | None, *, overrides: Mapping[str, Any] | None = None, resume: bool = False,
            on_log: Callable | None = None):
        from mitsnerf.runs.fit import fit
        from mitsnerf.train import TrainConfig

        return fit(self.dataset, self.method, dict(overrides or self.config),
                   TrainConfig(steps=STEPS, batch_rays=BATCH_RAYS, log_every=1, seed=0),
                   None if out is None else self.work / out, progress=self.progress, resume=resume,
                   on_log=on_log, deterministic=nondeterminism() is None)


def check_method(name: str, *, overrides: Mapping[str, Any] | None = None, work: Path | None = None,
                 progress: bool = False) -> ConformanceReport:
    """Run the suite on registered method ``name`` with its ``tiny`` settings and ``overrides`` over them,
    in ``work`` (default: a temporary directory, removed after)."""
    from mitsnerf.methods import get_method

    method = get_method(name)
    config = apply_overrides(dict(method.tiny), dict(overrides or {}))
    if work is not None:
        return _run_all(name, config, Path(work), progress)
    with tempfile.TemporaryDirectory(prefix="mitsnerf-check-") as tmp:
        return _run_all(name, config, Path(tmp), progress)


def _run_all(name: str, config: dict, work: Path, progress: bool) -> ConformanceReport:
    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.generate import generate_dataset
    from mitsnerf.scene.spec import parse_scene

    root = generate_dataset(parse_scene(TINY_SCENE, "conformance tiny scene"), work / "data", progress=False)
    ctx = _Context(name, config, load_dataset(root), work, progress)
    outcomes: list[Outcome] = []
    for promise, check, needs in PROMISES:
        blocked = [o.promise for o in outcomes if o.promise in needs and o.passed is not True]
        if blocked:
            outcomes.append(Outcome(promise, None, f"needs {', '.join(blocked)}"))
            continue
        outcomes.append(_attempt(promise, check, ctx))
    return ConformanceReport(name, tuple(outcomes), config)


def _attempt(promise: str, check: Callable[[_Context], str], ctx: _Context) -> Outcome:
    try:
        note = check(ctx)
    except Broken as exc:
        return Outcome(promise, False, str(exc))
    except Skipped as exc:
        return Outcome(promise, None, str(exc))
    except MitsnerfError as exc:  # the harness's own sentence (a NaN loss, a contract broken): what a user would see
        return Outcome(promise, False, f"{type(exc).__name__}: {exc}")
    except Exception as exc:  # the method's own code failed: the report names the promise and where it raised
        where = traceback.extract_tb(exc.__traceback__)[-1]
        return Outcome(promise, False, f"{type(exc).__name__}: {exc} (at {where.filename}:{where.lineno})")
    return Outcome(promise, True, note or "")


def _finite(name: str, values) -> None:
    a = np.asarray(values, dtype=np.float64)
    if not np.all(np.isfinite(a)):
        raise Broken(f"{name} has {int(np.sum(~np.isfinite(a)))} non-finite values")


def builds_with_parameters(ctx: _Context) -> str:
    from mitsnerf.methods.base import num_parameters
    from mitsnerf.runs.fit import build_model, scene_info

    try:
        model, _ = build_model(ctx.method, ctx.config, scene_info(ctx.dataset, ctx.dataset.views("train")), 0)
    except MethodError as exc:
        raise Broken(str(exc)) from None
    params = model.parameters()
    return f"{len(params)} parameter arrays, {num_parameters(params)} values"


def trains_and_evaluates(ctx: _Context) -> str:
    run = ctx.fit("run")
    ctx.runs["run"] = run
    losses = [entry["loss"] for entry in run.train.history if "loss" in entry]
    if run.train.steps != STEPS or not losses:
        raise Broken(f"trained {run.train.steps} of {STEPS} steps, logged {len(losses)} losses")
    _finite("the training loss", losses)
    test = ctx.dataset.views("test")
    if len(run.renders) != len(test.cameras):
        raise Broken(f"rendered {len(run.renders)} of {len(test.cameras)} test views")
    for i, (rendered, image) in enumerate(zip(run.renders, test.images)):
        if rendered.rgb.shape != image.shape:
            raise Broken(f"test view {i} rendered {rendered.rgb.shape}, the view is {image.shape}")
        _finite(f"test view {i}", rendered.rgb)
    _finite("psnr_test", run.scores["psnr_test"])
    _check_learned(ctx, run.model)
    files = ("config.json", "params.npz", "metrics.json", "checkpoint.npz")
    missing = [f for f in files if not (ctx.work / "run" / f).is_file()]
    if missing:
        raise Broken(f"the run directory lacks {', '.join(missing)}")
    return f"{STEPS} steps, PSNR {run.scores['psnr_test']:.2f} dB"


def _check_learned(ctx: _Context, model) -> None:
    """Training moved the parameters: some differ from a fresh model's of the same seed."""
    from mitsnerf.runs.fit import build_model, scene_info

    train = ctx.dataset.views("train")
    fresh, _ = build_model(ctx.method, ctx.config, scene_info(ctx.dataset, train), 0)
    before, after = _arrays(fresh.parameters()), _arrays(model.parameters())
    if before.keys() == after.keys() and all(np.array_equal(before[k], after[k]) for k in before):
        raise Broken(f"after {STEPS} steps every parameter is as initialised: the optimiser's values never reached "
                     "the model (set_parameters)")


def sigterm_checkpoints(ctx: _Context) -> str:
    from mitsnerf.errors import Interrupted
    from mitsnerf.train.checkpoint import CHECKPOINT_FILE, load_checkpoint

    if threading.current_thread() is not threading.main_thread():
        raise Skipped("signals reach the main thread only; run the suite there")

    def stop(entry: dict, model) -> None:
        if entry.get("step") == STOP_AT:
            os.kill(os.getpid(), signal.SIGTERM)

    try:
        ctx.fit("stopped", on_log=stop)
    except Interrupted as exc:
        if exc.signum != signal.SIGTERM:
            raise Broken(f"stopped by signal {exc.signum}, not SIGTERM") from None
    else:
        raise Broken(f"SIGTERM at step {STOP_AT} did not stop training")
    step = load_checkpoint(ctx.work / "stopped" / CHECKPOINT_FILE).step
    if step != STOP_AT:
        raise Broken(f"SIGTERM after step {STOP_AT} left the checkpoint of step {step}")
    return f"checkpoint of step {STOP_AT}"


#: How far a resumed run's parameters may lie from the run never stopped where the backend's float atomics
#: sum gradients in no fixed order (CUDA): measured 1.5e-8 to 1.2e-7 on an H200 (ngp, voxel, tensorf,
#: mitsuba-inverse); a resume that loses the optimiser's moments, the batch generator or the schedule moves
#: a parameter by about a learning rate (1e-3 to 1e-1) a step.
RESUME_ATOL = 1e-5


def parameter_gaps(a: Mapping[str, np.ndarray], b: Mapping[str, np.ndarray]) -> dict[str, float]:
    """Per key of ``a``, the largest ``|a - b|`` (``inf`` for another shape, NaN where either holds a NaN).

    >>> parameter_gaps({"w": np.array([1.0, 2.0])}, {"w": np.array([1.0, 2.5])})
    {'w': 0.5}
    """
    return {k: float(np.max(np.abs(a[k] - b[k]), initial=0.0)) if a[k].shape == b[k].shape else np.inf for k in a}


def resume_equals_the_run_never_stopped(ctx: _Context) -> str:
    from mitsnerf.runs.fit import resume_run

    resumed = resume_run(ctx.work / "stopped", progress=ctx.progress, dataset=ctx.dataset)
    a, b = _arrays(ctx.runs["run"].model.parameters()), _arrays(resumed.model.parameters())
    if a.keys() != b.keys():
        raise Broken(f"the resumed run has parameters {sorted(b)}, the run never stopped {sorted(a)}")
    why = nondeterminism()
    atol = 0.0 if why is None else RESUME_ATOL
    gap = parameter_gaps(a, b)
    differ = [k for k in a if not gap[k] <= atol]  # a NaN on either side is a difference
    if differ:
        raise Broken(f"parameters {', '.join(differ)} differ from the run never stopped "
                     f"(largest difference {max(gap[k] for k in differ):.3g}"
                     + (")" if why is None else f", more than {atol:g})"))
    if why is None:
        return f"{len(a)} parameter arrays bit-identical after stopping at step {STOP_AT} of {STEPS}"
    return (f"{len(a)} parameter arrays within {atol:g} (largest difference {max(gap.values()):.2g}) after stopping "
            f"at step {STOP_AT} of {STEPS}, not bit for bit: {why}")


def renders_a_saved_run(ctx: _Context) -> str:
    from mitsnerf.runs.fit import load_run

    model, _, config = load_run(ctx.work / "run")
    ref = ctx.runs["run"].renders[0]
    test = ctx.dataset.views("test")
    again = model.render_view(test.cameras[0], pixel_center=test.pixel_center, footprint=config["eval"]["footprint"])
    if again.rgb.shape != ref.rgb.shape:
        raise Broken(f"the saved run renders {again.rgb.shape}, the run rendered {ref.rgb.shape}")
    diff = float(np.max(np.abs(again.rgb - ref.rgb)))
    if diff > 1e-4 * max(1.0, float(np.max(np.abs(ref.rgb)))):
        raise Broken(f"the saved run renders test view 0 differently from the run (largest difference {diff:.3g})")
    return "test view 0 as rendered by the run"


def exports_its_density(ctx: _Context) -> str:
    from mitsnerf.fields.protocols import DensityField
    from mitsnerf.methods.base import HasField
    from mitsnerf.runs.export import export_run

    model = ctx.runs["run"].model
    if not (isinstance(model, HasField) and isinstance(model.field(), DensityField)):
        raise Skipped("the method has no queryable density")
    paths = export_run(ctx.work / "run", ctx.work / "export", resolution=8)
    sigma_t = np.load(paths["sigma_t.npy"])
    if sigma_t.shape != (8, 8, 8) or np.any(sigma_t < 0):
        raise Broken(f"the exported sigma_t has shape {sigma_t.shape} and minimum {float(np.min(sigma_t)):g}")
    _finite("the exported sigma_t", sigma_t)
    rel_l1 = ctx.runs["run"].scores.get("density_rel_l1")
    if rel_l1 is None:
        raise Broken("the run has a queryable density but no density score (density_rel_l1)")
    _finite("density_rel_l1", rel_l1)
    return f"sigma_t exported; density rel L1 {rel_l1:.3f}"


def other_settings_refused(ctx: _Context) -> str:
    from mitsnerf.errors import DatasetError
    from mitsnerf.runs.fit import method_config

    lr = method_config(ctx.method, ctx.config).lr
    try:
        ctx.fit("stopped", overrides={**ctx.config, "lr": 2 * lr}, resume=True)
    except DatasetError as exc:
        if "method_config" not in str(exc) or "lr" not in str(exc):
            raise Broken(f"refused, but without naming method_config and lr: {exc}") from None
        return "refused, naming method_config and lr"
    raise Broken(f"resuming with lr {2 * lr:g} instead of {lr:g} was accepted")


def _arrays(params: Mapping[str, Any]) -> dict[str, np.ndarray]:
    return {k: np.array(v.numpy() if hasattr(v, "numpy") else v) for k, v in params.items()}


#: ``(promise, check, promises it needs)``, in the order they run.
PROMISES: tuple[tuple[str, Callable[[_Context], str], tuple[str, ...]], ...] = (
    ("builds, with parameters to train", builds_with_parameters, ()),
    ("trains and evaluates", trains_and_evaluates, ("builds, with parameters to train",)),
    ("SIGTERM checkpoints the last completed step", sigterm_checkpoints, ("builds, with parameters to train",)),
    ("resume equals the run never stopped", resume_equals_the_run_never_stopped,
     ("trains and evaluates", "SIGTERM checkpoints the last completed step")),
    ("renders a saved run", renders_a_saved_run, ("trains and evaluates",)),
    ("exports its density, which is scored", exports_its_density, ("trains and evaluates",)),
    ("a run of other settings is refused on resume", other_settings_refused,
     ("SIGTERM checkpoints the last completed step",)),
)
