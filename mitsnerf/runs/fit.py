"""One training run end to end: dataset -> method -> training -> evaluation -> files.

``fit`` is what ``mitsnerf train`` and every benchmark cell call. A run directory holds
``config.json``, ``params.npz``, ``history.json``, ``metrics.json``, the rendered test views
(``test/r_*.exr`` linear with opacity, ``.png`` sRGB previews) and ``checkpoint.npz``
(:mod:`mitsnerf.train.checkpoint`); it is written inside a temporary directory and renamed when
complete. While training, the directory holds only the latest checkpoint (every
``checkpoint_every`` steps, when interrupted, and the last good one after a NaN or diverging
loss), which ``fit(..., resume=True)`` / :func:`resume_run` continue from and :func:`load_run`
reads back.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mitsnerf import env
from mitsnerf.config import from_dict, from_saved, to_dict
from mitsnerf.data.arrays import read_npz
from mitsnerf.data.atomic import atomic_dir, atomic_write_json
from mitsnerf.data.dataset import Dataset, Views, load_dataset
from mitsnerf.data.images import write_exr, write_png
from mitsnerf.data.verify import verify_dataset
from mitsnerf.errors import CLI, DatasetError, DiskFullError, OutputError, Placeholder, UsageError, Words
from mitsnerf.fields.protocols import DensityField
from mitsnerf.math.box import Box
from mitsnerf.methods import check_model, get_method, methods
from mitsnerf.methods.base import HasField, Model, ParameterShapeError, SceneInfo, num_parameters
from mitsnerf.outputs import progress_log
from mitsnerf.render.background import make_background
from mitsnerf.render.camera import Rendered
from mitsnerf.runs.directory import RUN_FILES, remove_run_files
from mitsnerf.scoring.images import image_scores
from mitsnerf.scoring.reference import Reference, load_reference
from mitsnerf.scoring.views import score_views
from mitsnerf.train import PixelData, TrainConfig, TrainResult, TrainState, make_optimizer, memory, train
from mitsnerf.train.checkpoint import CHECKPOINT_FILE, Checkpointer, load_checkpoint, restore_optimizer
from mitsnerf.train.checkpointing import interrupted_message
from mitsnerf.train.evaluate import EvalConfig, render_views, stack_rgb
from mitsnerf.train.threads import one_thread, refuse_nondeterministic


@dataclass
class RunResult:
    method: str
    config: dict
    """The run config: method, method_config, train, eval, dataset (its path and manifest hash, ``dataset_hash``)
    (what ``config.json`` holds)."""
    train: TrainResult
    scores: dict
    """:func:`mitsnerf.scoring.views.score_views` of the test views, plus ``psnr_train``."""
    renders: list[Rendered]
    slices: dict
    """Central slices of the true and learned density (for the report)."""
    num_parameters: int
    eval_seconds: float
    model: Model
    model_bytes: int = 0
    """The size of the saved model, ``params.npz`` (:func:`parameter_file`), in bytes."""
    peaks: dict = field(default_factory=dict)
    """The run's own peak memory (:func:`mitsnerf.train.memory.peaks`: ``peak_memory_mb``, ``peak_rss_mb``,
    ``peak_rss_reset``), from its start to the end of its evaluation."""
    provenance: dict = field(default_factory=dict)
    """:func:`mitsnerf.env.provenance` when the run started: the commit of the code it imported, not of the
    checkout when it was written (the files record it; empty: taken when written)."""

    def metrics(self) -> dict:
        """Everything ``metrics.json`` records: scores, budget, timings, the run's peak memory and its model's
        size (as a benchmark cell's)."""
        return {
            "method": self.method,
            "given": ", ".join(("images",) + tuple(self.model.given())),
            "rung": self.model.rung,
            **({"rung_basis": list(self.model.rung_basis())} if self.model.rung == "single scattering" else {}),
            "footprint": self.config["eval"]["footprint"],
            "budget": from_dict(TrainConfig, self.config["train"]).budget,
            "steps": self.train.steps,
            "stopped_by": self.train.stopped_by,
            "train_seconds": self.train.seconds,
            "rays_per_s": self.train.rays_per_s,
            "samples_per_s": self.train.samples_per_s,
            "num_parameters": self.num_parameters,
            "model_bytes": self.model_bytes,
            **self.peaks,
            "eval_seconds": self.eval_seconds,
            **self.scores,
        }

    def summary(self, out: object = None) -> str:
        """The line ``mitsnerf train`` prints: test PSNR (medium pixels), footprint, train PSNR, steps, rays/s, peak
        memory and the model's size."""
        m = self.metrics()
        medium = "" if m.get("psnr_test_medium") is None else f" ({m['psnr_test_medium']:.2f} dB on medium pixels)"
        rate = "no steps run" if m["rays_per_s"] is None else f"{m['rays_per_s']:.0f} rays/s"
        peak = f", peak {m['peak_memory_mb']:.0f} MiB" if m.get("peak_memory_mb") is not None else ""
        k = m["footprint"]
        return (f"{self.method}: test PSNR {m['psnr_test']:.2f} dB{medium}, footprint {k}x{k}, "
                f"train PSNR {m['psnr_train']:.2f} dB, {m['steps']} steps in {m['train_seconds']:.1f} s, "
                f"{rate}{peak}, model {m['model_bytes'] / 1e6:.3f} MB" + ("" if out is None else f" -> {out}"))


def scene_info(dataset: Dataset, train_views: Views) -> SceneInfo:
    """What a method is given of ``dataset`` before training: its box, background, largest training radiance,
    manifest and training views."""
    return SceneInfo(
        box=dataset.box,
        background=make_background(dataset.background, dataset.root),
        radiance_max=float(np.percentile(train_views.images, 99.9)),
        manifest=dataset.manifest or None,
        train_views=train_views,
    )


def dataset_config(dataset: Dataset) -> dict:
    """How to open ``dataset`` again (path, box and load options), and which it is (its manifest's
    ``hash``, None for foreign data), for run configs and checkpoints."""
    return {
        "dataset": str(Path(dataset.root).resolve()),
        "dataset_hash": (dataset.manifest or {}).get("hash"),
        "dataset_options": {
            "pixel_center": dataset.pixel_center,
            "background": list(dataset.png_background),
            "color_space": dataset.color_space,
            "box": dataset.box.to_list(),
            "box_source": dataset.box_source,
        },
    }


def open_dataset(config: Mapping[str, Any], where: Path | None = None) -> Dataset:
    """The dataset a run config names (see :func:`dataset_config`), with the box the run used."""
    if "dataset" not in config:
        raise DatasetError(where, "dataset", "the run config does not name its dataset")
    options = config.get("dataset_options") or {}
    box = Box.from_list(options["box"]) if options.get("box") else None
    return load_dataset(config["dataset"], box=box, pixel_center=options.get("pixel_center"),
                        background=options.get("background"), color_space=options.get("color_space"))


#: Train settings a resumed run may change; the others must match the checkpoint's.
RESUMABLE_CHANGES = ("steps", "seconds", "log_every", "checkpoint_every", "divergence_factor", "divergence_patience")


def _check_resumable(saved: Mapping[str, Any], current: Mapping[str, Any], where: Path) -> None:
    if saved.get("method") != current["method"]:
        raise DatasetError(where, "method", f"the checkpoint is of {saved.get('method')!r}, not {current['method']!r}")
    saved = {**saved, "method_config": to_dict(method_config(current["method"], saved.get("method_config"), where)),
             "train": to_dict(from_saved(TrainConfig, saved.get("train"), source=where, prefix="train."))}
    saved, current = (json.loads(json.dumps(c)) for c in (saved, current))  # tuples vs JSON lists
    old = saved["method_config"]
    if old != current["method_config"]:
        diff = sorted(
            k for k in set(old) | set(current["method_config"]) if old.get(k) != current["method_config"].get(k)
        )
        raise DatasetError(
            where, "method_config", f"differs from the checkpoint's in {', '.join(diff)}; resume with the same settings"
        )
    for key, value in current["train"].items():
        was = (saved.get("train") or {}).get(key)
        if key not in RESUMABLE_CHANGES and was != value:
            raise DatasetError(where, f"train.{key}", f"the checkpoint was trained with {was!r}, not {value!r}; "
                                                      f"only {', '.join(RESUMABLE_CHANGES)} may change on resume")


#: What :func:`check_same_dataset` tells a resume on another dataset to do instead (``{dataset}``: how the surface
#: called names the dataset argument).
RESUME_ELSEWHERE = "resume it on its own dataset (leave {dataset} out), or train a new run elsewhere"


def check_same_dataset(saved: Mapping[str, Any], dataset: Dataset, run_dir: Path, option: str = "resume",
                       advice: str = RESUME_ELSEWHERE, words: Words = CLI) -> None:
    """Refuse to use the run in ``run_dir`` (config ``saved``) with another dataset than it trained on (to resume
    it, to score its renders): the same manifest ``hash`` where both have one (a moved dataset is the same),
    else the same path. A :class:`~mitsnerf.errors.UsageError` of the setting ``option`` (in ``words``) naming
    the run, both datasets and ``advice``."""
    was, was_hash = saved.get("dataset"), saved.get("dataset_hash")
    now, now_hash = str(Path(dataset.root).resolve()), (dataset.manifest or {}).get("hash")
    same = was_hash == now_hash if (was_hash and now_hash) else was == now
    if not same:
        def tag(h: str | None) -> str:
            return f" (manifest hash {h[:12]})" if h else ""

        raise UsageError(words.name(option), f"the run in {run_dir} trained on {was}{tag(was_hash)}, not on {now}"
                                             f"{tag(now_hash)}; {advice.format(dataset=words.name('dataset'))}")


def run_method(config: Mapping[str, Any], where: Path) -> str:
    """The known method a run config (of ``config.json`` or a checkpoint at ``where``) names."""
    if not isinstance(config, Mapping):
        raise DatasetError(where, None, f"the run config must be a JSON object, got {type(config).__name__}")
    method = config.get("method")
    if method is None:
        raise DatasetError(where, "method", "missing: the run does not say which method trained it")
    problem = methods().why_not(method)
    if problem:
        raise DatasetError(where, "method", problem)
    return method


def method_config(method: str, overrides: Mapping[str, Any] | None, source: Path | None = None):
    """The method's config with ``overrides``; a bad one is a SpecError at ``source``, ``method_config.FIELD``
    there. With ``source`` (the run's file that saved them), the overrides are a run's settings, read as saved
    (:func:`mitsnerf.config.from_saved`: a setting added since takes the value the run trained with, not today's
    default)."""
    if source is None:
        return from_dict(get_method(method).config_type, overrides or {})
    return from_saved(get_method(method).config_type, overrides or {}, source=source, prefix="method_config.")


def build_model(method: str, overrides: Mapping[str, Any] | None, info: SceneInfo, seed: int,
                source: Path | None = None) -> tuple[Model, Any]:
    """``(model, config)`` of ``method`` for the scene; a :class:`~mitsnerf.errors.MethodError` if the model has
    nothing to train (:func:`mitsnerf.methods.check_model`), before anything is written."""
    config = method_config(method, overrides, source)
    model = get_method(method).model_type(config, info, seed)
    check_model(get_method(method), model)
    return model, config


def set_checked(model: Model, values: Mapping[str, Any], where: Path, method: str, run_dir: Path) -> None:
    """``model.set_parameters(values)``; a value shaped unlike the model's config builds is a DatasetError
    naming ``where`` and the parameter."""
    try:
        model.set_parameters(values)
    except ParameterShapeError as e:
        raise DatasetError(where, e.key, f"{e} from the run's config: the run was written by another version of "
                           f"method {method!r}{_written_by(run_dir)}; retrain it") from None


def _start(out_dir: Path | None, run_config: dict, model: Model, lr: float, resume: bool, words: Words = CLI):
    """``(checkpointer, state)``: where checkpoints go, and the state to continue from (None: a fresh run)."""
    if out_dir is None:
        if resume:
            raise ValueError("resume: needs the run directory (out_dir) holding the checkpoint")
        return None, None
    path = Path(out_dir) / CHECKPOINT_FILE
    checkpointer = Checkpointer(path, run_config, words)
    if not resume:
        remove_run_files(Path(out_dir))  # a fresh run: the old one's files go now, when training starts
        return checkpointer, None
    ckpt = load_checkpoint(path)
    _check_resumable(ckpt.config, run_config, path)
    opt = make_optimizer(model, lr)
    restore_optimizer(opt, ckpt, path)
    model.load_extra_state(ckpt.extra_state)
    set_checked(model, opt, path, run_config["method"], Path(out_dir))
    return checkpointer, TrainState(opt, ckpt.step, ckpt.elapsed, ckpt.history, ckpt.monitor)


def fit(
    dataset: Dataset,
    method: str,
    method_overrides: Mapping[str, Any] | None = None,
    train_config: TrainConfig = TrainConfig(),
    out_dir: Path | None = None,
    *,
    eval_config: EvalConfig = EvalConfig(),
    progress: bool = True,
    resume: bool = False,
    on_log: Callable[[dict, Model], None] | None = None,
    reference: Reference | None = None,
    oracle: dict | None = None,
    deterministic: bool = False,
    words: Words = CLI,
) -> RunResult:
    """Train ``method`` on ``dataset``, then render and score every test view.

    ``reference``: the test views' :class:`mitsnerf.scoring.reference.Reference` if the caller has it
    (else built here); ``oracle``: the oracle's test metrics at the same footprint, for the
    error budget. With ``out_dir``, checkpoints go to ``out_dir/checkpoint.npz`` (a fresh run
    first removes an old run's files there, :func:`mitsnerf.runs.directory.remove_run_files`); ``resume=True``
    continues from it instead, which must be of
    the same method, method settings and training settings (except :data:`RESUMABLE_CHANGES`).
    ``on_log(entry, model)`` runs after each history entry, off the training clock (e.g. a
    held-out curve, :class:`mitsnerf.bench.worker.CurveRecorder`); a resumed run calls it again on
    the checkpoint's last entry when that is the checkpoint's step (a signal may have stopped it
    there), so it must do nothing the second time for an entry it finished. ``deterministic``: train on one
    thread (:mod:`mitsnerf.train.threads`), recorded in the run config so a resume does too. ``words``: how
    the messages of an interrupted run say to continue (:class:`mitsnerf.errors.Words`).
    The caller holds the run directory (:func:`mitsnerf.runs.directory.claim_run_dir`).
    """
    refuse_nondeterministic(deterministic)  # before _start empties or reads the run directory
    train_views = dataset.views("train")
    ref = reference or load_reference(dataset, "test")
    rss_reset = memory.start()  # the run's own peaks from here: its scene is loaded, what ran before is freed
    started = env.provenance()  # the code this process imported: the checkout may move while it trains
    model, config = build_model(method, method_overrides, scene_info(dataset, train_views), train_config.seed)
    run_config = {"method": method, "method_config": to_dict(config), "train": to_dict(train_config),
                  "eval": to_dict(eval_config), "deterministic": bool(deterministic), **dataset_config(dataset)}
    checkpointer, state = _start(out_dir, run_config, model, config.lr, resume, words)
    data = PixelData.from_views(train_views.images, train_views.cameras, train_views.pixel_center)
    if state is not None and on_log is not None and state.history and state.history[-1].get("step") == state.step:
        on_log(state.history[-1], model)  # a signal may have stopped the hook on the checkpoint's own entry
    with one_thread(deterministic):
        result, _ = train(
            model,
            data,
            train_config,
            config.lr,
            state=state,
            progress=progress,
            checkpointer=checkpointer,
            on_log=None if on_log is None else (lambda entry: on_log(entry, model)),
        )
    progress_log(progress)(f"[train] {method}: {result.steps} steps in {result.seconds:.0f} s; rendering the "
                           f"{len(ref.cameras)} test views to score them ...")
    try:
        run = evaluate_run(model, method, run_config, result, dataset, ref, eval_config, oracle)
        run.peaks, run.provenance = memory.peaks(rss_reset), started
        if out_dir is not None:
            write_run(run, dataset, out_dir, dataset.views("test").names)
    except KeyboardInterrupt as exc:  # trained and checkpointed: a resume only evaluates
        if checkpointer is None:
            raise
        raise interrupted_message(exc, checkpointer.path, result.steps, " while evaluating", words) from None
    except DiskFullError as exc:  # the run directory is as it was, with the final checkpoint: a resume only evaluates
        if checkpointer is None:
            raise
        raise DiskFullError(exc.path, exc.reason, f"{exc.kept}; {checkpointer.kept()}", exc.writing) from exc
    return run


def score_model(model: Model, ref: Reference, eval_config: EvalConfig,
                oracle: dict | None = None) -> tuple[dict, list[Rendered], dict, float]:
    """Render ``ref``'s views with the footprint of ``eval_config`` and score them (the density too, where the
    model has a queryable one): ``(scores, renders, density slices, render seconds)``. A Monte Carlo model's renders
    are also scored without their own variance where it renders them a second time independently
    (:func:`monte_carlo_variance`)."""
    renders, seconds = render_views(model, ref.cameras, pixel_center=ref.pixel_center, footprint=eval_config.footprint)
    images = stack_rgb(renders)
    variance, note, again = monte_carlo_variance(model, ref, eval_config.footprint, images)
    field = model.field() if isinstance(model, HasField) else None
    density = field.density if isinstance(field, DensityField) else None
    scores, slices = score_views(images, ref, density, oracle=oracle,
                                 density_resolution=eval_config.density_resolution,
                                 od_samples=eval_config.od_samples, variance=variance)
    if note is not None:
        scores["mc_note"] = note
    return scores, renders, slices, seconds + again


def monte_carlo_variance(model: Model, ref: Reference, footprint: int,
                         first: np.ndarray) -> tuple[np.ndarray | None, str | None, float]:
    """``(Var per pixel (V, H, W, 3) or None, a note or None, seconds)`` of a model's test renders ``first``: from its
    independent second renders (:meth:`~mitsnerf.methods.base.Model.render_view_independent`,
    :func:`mitsnerf.scoring.variance.pair_variance`); None for a model whose renders are not Monte Carlo, and for
    one without a second render, with the note that its scores keep their own variance."""
    from mitsnerf.scoring.variance import pair_variance

    if not model.monte_carlo_renders:
        return None, None, 0.0
    start = time.perf_counter()
    again = [model.render_view_independent(cam, pixel_center=ref.pixel_center, footprint=footprint)
             for cam in ref.cameras[:1]]
    if again[0] is None:
        return None, ("raw: its renders are Monte Carlo and it makes no independent second render, so its scores "
                      "keep their own Monte Carlo variance"), 0.0
    again += [model.render_view_independent(cam, pixel_center=ref.pixel_center, footprint=footprint)
              for cam in ref.cameras[1:]]
    second = np.stack([r.rgb for r in again if r is not None]).astype(np.float32)
    return pair_variance(first, second), None, time.perf_counter() - start


def evaluate_run(model: Model, method: str, run_config: dict, result: TrainResult, dataset: Dataset,
                 ref: Reference, eval_config: EvalConfig, oracle: dict | None) -> RunResult:
    """Render the test views (and a few training views) with the run's footprint and score them."""
    k = eval_config.footprint
    scores, renders, slices, seconds = score_model(model, ref, eval_config, oracle)
    train_views = dataset.views("train")
    n = min(eval_config.train_eval_views, len(train_views.cameras))
    train_renders, _ = render_views(model, train_views.cameras[:n], pixel_center=train_views.pixel_center, footprint=k)
    scores["psnr_train"] = image_scores(stack_rgb(train_renders), train_views.images[:n], with_ssim=False)["psnr_test"]
    params = model.parameters()
    return RunResult(method, run_config, result, scores, renders, slices, num_parameters(params), seconds, model,
                     len(parameter_file(params)))


def parameter_file(params: Mapping[str, Any]) -> bytes:
    """The bytes of ``params.npz``: the parameters as a numpy ``.npz`` (dotted names as keys, uncompressed).

    >>> len(parameter_file({"x": np.zeros((4, 3), np.float32)})) > 48
    True
    """
    import io

    arrays: dict[str, Any] = {k: np.asarray(v.numpy() if hasattr(v, "numpy") else v) for k, v in params.items()}
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def save_parameters(path: Path, params: Mapping[str, Any]) -> None:
    """Parameters as a numpy ``.npz`` (:func:`parameter_file`), written atomically."""
    from mitsnerf.data.atomic import atomic_write_bytes

    atomic_write_bytes(path, parameter_file(params))


def write_run(run: RunResult, dataset: Dataset, out_dir: Path, test_names) -> None:
    """Write the run into ``out_dir``, renamed into place whole (:func:`mitsnerf.data.atomic.atomic_dir`).

    Entries of an existing ``out_dir`` that a run does not write (:data:`mitsnerf.runs.directory.RUN_FILES`:
    renders, exports, a user's notes) are carried into the new directory (hard links, else copies),
    so rewriting a run loses nothing else that was there.
    """
    out_dir = Path(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    with atomic_dir(out_dir, overwrite=True) as tmp:
        provenance = run.provenance or env.provenance()
        atomic_write_json(tmp / "config.json", {**run.config, "provenance": provenance})  # the dataset's absolute path
        if (out_dir / CHECKPOINT_FILE).is_file():  # the final checkpoint fit() wrote there
            shutil.copy2(out_dir / CHECKPOINT_FILE, tmp / CHECKPOINT_FILE)
        save_parameters(tmp / "params.npz", run.model.parameters())
        atomic_write_json(tmp / "history.json", run.train.history)
        atomic_write_json(tmp / "metrics.json", {**run.metrics(), "provenance": provenance})
        (tmp / "test").mkdir()
        for name, rendered in zip(test_names, run.renders):
            stem = Path(name).name
            write_exr(
                tmp / "test" / f"{stem}.exr",
                np.concatenate([rendered.rgb, rendered.opacity[..., None]], axis=-1),
                alpha="opacity",
            )
            write_png(tmp / "test" / f"{stem}.png", rendered.rgb)
        _carry_over(out_dir, tmp)


def _link_or_copy(src: str, dst: str) -> None:
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def _carry_over(old: Path, new: Path) -> None:
    """Link (else copy) into ``new`` every entry of ``old`` that a run does not write."""
    if not old.is_dir():
        return
    for p in old.iterdir():
        if p.name in RUN_FILES or (new / p.name).exists():
            continue
        if p.is_dir() and not p.is_symlink():
            shutil.copytree(p, new / p.name, symlinks=True, copy_function=_link_or_copy)
        else:
            _link_or_copy(str(p), str(new / p.name))


def resume_run(run_dir: Path, train_overrides: Mapping[str, Any] | None = None, *, progress: bool = True,
               dataset: Dataset | None = None, verify_hashes: bool = True, words: Words = CLI) -> RunResult:
    """Continue the run in ``run_dir`` from its checkpoint (``mitsnerf train --resume``).

    Everything comes from the checkpoint's config (method, settings, dataset, box, one thread or
    not); ``train_overrides`` may change only :data:`RESUMABLE_CHANGES`, e.g. ``{"steps": 2000}``
    to train longer (the learning-rate schedule then stretches to the new length). The dataset
    the checkpoint names is verified (:func:`mitsnerf.data.verify.verify_dataset`) when opened
    here. A finished run (``metrics.json``) resumes only with more steps. ``words``: the settings its messages
    advise (:class:`mitsnerf.errors.Words`).
    """
    run_dir = Path(run_dir)
    path = run_dir / CHECKPOINT_FILE
    ckpt = load_checkpoint(path)
    refuse_nondeterministic(bool(ckpt.config.get("deterministic")), str(path),
                            f"the run was trained with {words(deterministic=True)}, which this backend cannot "
                            "continue (resume it with MITSNERF_VARIANT=llvm_ad_rgb): ")
    trained = to_dict(from_saved(TrainConfig, ckpt.config.get("train") or {}, source=path, prefix="train."))
    train_config = from_dict(TrainConfig, {**trained, **dict(train_overrides or {})})
    if ckpt.step >= train_config.steps and (run_dir / "metrics.json").is_file():
        raise OutputError(run_dir, None, f"the run finished at step {ckpt.step} (metrics.json); nothing to resume: "
                                         f"pass {words(steps=Placeholder('N'))} (N > {ckpt.step}) to train it on")
    eval_config = from_saved(EvalConfig, ckpt.config.get("eval") or {}, source=path, prefix="eval.")
    method = run_method(ckpt.config, path)
    settings = to_dict(method_config(method, ckpt.config.get("method_config"), path))  # before the data loads
    if dataset is None:
        dataset = open_dataset(ckpt.config, path)
        verify_dataset(dataset, hashes=verify_hashes, words=words)
    check_same_dataset(ckpt.config, dataset, run_dir, words=words)
    return fit(dataset, method, settings, train_config, run_dir,
               eval_config=eval_config, progress=progress, resume=True,
               deterministic=bool(ckpt.config.get("deterministic")), words=words)


def _written_by(run_dir: Path) -> str:
    """`` (commit C)`` of the run's provenance in ``config.json``, or nothing."""
    try:
        commit = json.loads((run_dir / "config.json").read_text())["provenance"]["commit"]
    except (OSError, ValueError, KeyError, TypeError):
        return ""
    return f" (commit {str(commit)[:12]})" if commit else ""


def load_run(run_dir: Path) -> tuple[Model, Dataset, dict]:
    """A trained run back: ``(model, dataset, config)``, for ``mitsnerf render`` and ``export``.

    Parameters and model state come from ``checkpoint.npz`` (also present in an unfinished
    or interrupted run), else from ``params.npz`` with ``config.json``.
    """
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise DatasetError(run_dir, None, "run directory not found")
    ckpt_path = run_dir / CHECKPOINT_FILE
    if ckpt_path.is_file():
        ckpt = load_checkpoint(ckpt_path)
        config, params, extra, where = ckpt.config, ckpt.params, ckpt.extra_state, ckpt_path
        config_where = ckpt_path
    else:
        from mitsnerf.data.transforms import read_json

        where = run_dir / "params.npz"
        if not (run_dir / "config.json").is_file() or not where.is_file():
            raise DatasetError(
                run_dir, None, "neither checkpoint.npz nor config.json + params.npz: not a run directory"
            )
        config_where = run_dir / "config.json"
        config = read_json(config_where)
        params = read_npz(where, "parameter file")
        extra = {}
    method = run_method(config, config_where)
    method_config(method, config.get("method_config"), config_where)  # checked before the data loads
    dataset = open_dataset(config, config_where)
    info = scene_info(dataset, dataset.views("train"))
    seed = int((config.get("train") or {}).get("seed", 0))
    model, _ = build_model(method, config.get("method_config"), info, seed, config_where)
    current = model.parameters()
    missing = sorted(set(current) - set(params))
    if missing:
        raise DatasetError(where, None, f"missing parameters {', '.join(missing)} of method {method!r}")
    set_checked(model, {k: type(current[k])(np.ascontiguousarray(params[k])) for k in current}, where, method, run_dir)
    model.load_extra_state(extra)
    return model, dataset, config
