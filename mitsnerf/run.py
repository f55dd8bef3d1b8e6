"""One training run end to end: dataset -> method -> training -> evaluation -> files.

``fit`` is what ``mitsnerf train`` and every benchmark cell call. A run directory
holds ``config.json``, ``params.npz``, ``history.json``, ``metrics.json``, the
rendered test views (``test/r_*.exr`` linear, ``.png`` sRGB previews) and
``checkpoint.npz`` (:mod:`mitsnerf.checkpoint`); it is written inside a temporary
directory and renamed when complete. While training, the directory holds only the
latest checkpoint (every ``checkpoint_every`` steps, on Ctrl-C, and the last good one
after a NaN or diverging loss), which ``fit(..., resume=True)`` / :func:`resume_run`
continue from and :func:`load_run` reads back.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from mitsnerf import env
from mitsnerf.checkpoint import CHECKPOINT_FILE, Checkpointer, load_checkpoint, restore_optimizer
from mitsnerf.config import from_dict, to_dict
from mitsnerf.data.atomic import atomic_dir, atomic_write_json
from mitsnerf.data.dataset import Dataset, load_dataset
from mitsnerf.data.images import write_exr, write_png
from mitsnerf.errors import DatasetError
from mitsnerf.evaluate import EvalResult, evaluate_views
from mitsnerf.math.metrics import psnr
from mitsnerf.methods import get_method
from mitsnerf.methods.base import Model, SceneInfo, num_parameters
from mitsnerf.render.background import make_background
from mitsnerf.render.rays import BOX_MAX, BOX_MIN
from mitsnerf.scene.generate import MEDIUM_OPACITY as MEDIUM_OPACITY_THRESHOLD
from mitsnerf.scene.generate import medium_mask
from mitsnerf.train import PixelData, TrainConfig, TrainResult, make_optimizer, train


@dataclass
class RunResult:
    method: str
    config: dict
    train: TrainResult
    test: EvalResult
    train_eval: EvalResult
    test_psnr_medium: float | None
    num_parameters: int
    model: Model

    def metrics(self) -> dict:
        return {
            "method": self.method,
            "psnr_test": self.test.psnr_mean,
            "psnr_test_per_view": self.test.psnr,
            "psnr_test_medium": self.test_psnr_medium,
            "ssim_test": self.test.ssim_mean,
            "ssim_test_per_view": self.test.ssim,
            "psnr_train": self.train_eval.psnr_mean,
            "train_seconds": self.train.seconds,
            "steps": self.train.steps,
            "rays_per_s": self.train.rays_per_s,
            "samples_per_s": self.train.samples_per_s,
            "num_parameters": self.num_parameters,
            "eval_seconds": self.test.seconds,
        }


def scene_info(dataset: Dataset, train_images: np.ndarray) -> SceneInfo:
    return SceneInfo(
        box_min=BOX_MIN,
        box_max=BOX_MAX,
        background=make_background(dataset.background, dataset.root),
        radiance_max=float(np.percentile(train_images, 99.9)),
        manifest=dataset.manifest or None,
    )


def dataset_config(dataset: Dataset) -> dict:
    """How to open ``dataset`` again (path and load options), for run configs and checkpoints."""
    return {
        "dataset": str(Path(dataset.root).resolve()),
        "dataset_options": {
            "pixel_center": dataset.pixel_center,
            "background": list(dataset.png_background),
            "color_space": dataset.color_space,
        },
    }


def open_dataset(config: Mapping[str, Any], where: Path | None = None) -> Dataset:
    """The dataset a run config names (see :func:`dataset_config`)."""
    if "dataset" not in config:
        raise DatasetError(where, "dataset", "the run config does not name its dataset")
    options = config.get("dataset_options") or {}
    return load_dataset(config["dataset"], pixel_center=options.get("pixel_center"),
                        background=options.get("background"), color_space=options.get("color_space"))


#: Train settings a resumed run may change; the others must match the checkpoint's.
RESUMABLE_CHANGES = ("steps", "seconds", "log_every", "checkpoint_every", "divergence_factor", "divergence_patience")


def _check_resumable(saved: Mapping[str, Any], current: Mapping[str, Any], where: Path) -> None:
    import json

    saved, current = (json.loads(json.dumps(c)) for c in (saved, current))  # tuples vs JSON lists
    if saved.get("method") != current["method"]:
        raise DatasetError(where, "method", f"the checkpoint is of {saved.get('method')!r}, not {current['method']!r}")
    if saved.get("method_config") != current["method_config"]:
        diff = sorted(k for k in set(saved.get("method_config") or {}) | set(current["method_config"])
                      if (saved.get("method_config") or {}).get(k) != current["method_config"].get(k))
        raise DatasetError(where, "method_config", f"differs from the checkpoint's in {', '.join(diff)}; resume with the same settings")
    for key, value in current["train"].items():
        if key not in RESUMABLE_CHANGES and (saved.get("train") or {}).get(key) != value:
            raise DatasetError(where, f"train.{key}", f"the checkpoint was trained with {(saved.get('train') or {}).get(key)!r}, "
                                                      f"not {value!r}; only {', '.join(RESUMABLE_CHANGES)} may change on resume")


def true_sigma_t(dataset: Dataset) -> np.ndarray | None:
    """The ground-truth ``sigma_t`` grid of a generated dataset (None for foreign data)."""
    path = dataset.root / "volume" / "sigma_t.npy"
    if not path.exists():
        return None
    try:
        return np.load(path)
    except (OSError, ValueError) as exc:
        raise DatasetError(path, None, f"cannot read the density grid: {exc}") from None


def medium_masks(sigma_t: np.ndarray, cameras, pixel_center: float = 0.5) -> np.ndarray:
    """(V, H, W) bool: pixels whose centre ray crosses the true medium.

    The rule of :func:`mitsnerf.scene.generate.medium_mask` (opacity ``1 - exp(-tau)`` above
    ``MEDIUM_OPACITY_THRESHOLD``), the one the dataset's noise floor is measured with, so a
    method's medium PSNR and the floor next to it are taken over the same pixels.
    """
    return np.stack([medium_mask(cam, sigma_t, MEDIUM_OPACITY_THRESHOLD, pixel_center) for cam in cameras])


def build_model(method: str, overrides: Mapping[str, Any] | None, info: SceneInfo, seed: int) -> tuple[Model, Any]:
    entry = get_method(method)
    config = from_dict(entry.config_type, overrides or {})
    return entry.model_type(config, info, seed), config


def fit(
    dataset: Dataset,
    method: str,
    method_overrides: Mapping[str, Any] | None = None,
    train_config: TrainConfig = TrainConfig(),
    out_dir: Path | None = None,
    *,
    progress: bool = True,
    max_train_eval_views: int = 4,
    resume: bool = False,
    on_log: Callable[[dict, Model], None] | None = None,
    test_masks: np.ndarray | None = None,
) -> RunResult:
    """Train ``method`` on ``dataset`` and evaluate it on every test view.

    ``test_masks`` (V, H, W): the test views' medium pixels if the caller has them already
    (else :func:`medium_masks` of the true grid, for datasets that have one).

    With ``out_dir``, checkpoints go to ``out_dir/checkpoint.npz`` (a fresh run first
    removes an old one there); ``resume=True`` continues from it instead, which must be
    of the same method, method settings and training settings (except
    :data:`RESUMABLE_CHANGES`).

    ``on_log(entry, model)`` is called after each training-history entry (the trainer's hook:
    its time is kept off the training clock, it may add keys to ``entry``), e.g. to evaluate
    held-out views during training (:class:`mitsnerf.bench.worker.CurveRecorder`).
    """
    train_views = dataset.views("train")
    test_views = dataset.views("test")
    pixel_center = train_views.pixel_center
    info = scene_info(dataset, train_views.images)
    model, config = build_model(method, method_overrides, info, train_config.seed)
    base_lr = train_config.lr or getattr(config, "lr", 1e-2)
    data = PixelData.from_views(train_views.images, train_views.cameras, pixel_center)
    run_config = {"method": method, "method_config": to_dict(config), "train": to_dict(train_config),
                  **dataset_config(dataset)}
    checkpointer, opt, start_step, elapsed, history = None, None, 0, 0.0, None
    if out_dir is not None:
        ckpt_path = Path(out_dir) / CHECKPOINT_FILE
        checkpointer = Checkpointer(ckpt_path, run_config, model)
        if resume:
            ckpt = load_checkpoint(ckpt_path)
            _check_resumable(ckpt.config, run_config, ckpt_path)
            opt = make_optimizer(model, base_lr)
            restore_optimizer(opt, ckpt, ckpt_path)
            model.load_extra_state(ckpt.extra_state)
            start_step, elapsed, history = ckpt.step, ckpt.elapsed, ckpt.history
        elif ckpt_path.exists():
            ckpt_path.unlink()
    elif resume:
        raise ValueError("resume: needs the run directory (out_dir) holding the checkpoint")
    result, _ = train(model, data, train_config, base_lr, opt=opt, start_step=start_step, elapsed=elapsed,
                      history=history, progress=progress, checkpointer=checkpointer,
                      on_log=None if on_log is None else (lambda entry: on_log(entry, model)))

    test_eval = evaluate_views(model, test_views.images, test_views.cameras, pixel_center=pixel_center)
    k = min(max_train_eval_views, len(train_views.cameras))
    train_eval = evaluate_views(model, train_views.images[:k], train_views.cameras[:k], pixel_center=pixel_center, keep_renders=False)

    psnr_medium = None
    sigma_t = true_sigma_t(dataset) if test_masks is None else None
    masks = test_masks if test_masks is not None else (
        medium_masks(sigma_t, test_views.cameras, pixel_center) if sigma_t is not None else None)
    if masks is not None:
        preds = np.clip(np.stack([r.rgb for r in test_eval.renders]), 0.0, 1.0)
        refs = np.clip(test_views.images, 0.0, 1.0)
        if masks.any():
            psnr_medium = float(np.mean([psnr(p, r, mask=m) for p, r, m in zip(preds, refs, masks) if m.any()]))

    run = RunResult(
        method=method,
        config=run_config,
        train=result,
        test=test_eval,
        train_eval=train_eval,
        test_psnr_medium=psnr_medium,
        num_parameters=num_parameters(model.parameters()),
        model=model,
    )
    if out_dir is not None:
        write_run(run, dataset, out_dir, test_views.names)
    return run


def save_parameters(path: Path, params: Mapping[str, Any]) -> None:
    """Parameters as a numpy ``.npz`` (dotted names as keys), written atomically."""
    import io

    from mitsnerf.data.atomic import atomic_write_bytes

    arrays = {k: np.asarray(v.numpy() if hasattr(v, "numpy") else v) for k, v in params.items()}
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    atomic_write_bytes(path, buf.getvalue())


def write_run(run: RunResult, dataset: Dataset, out_dir: Path, test_names) -> None:
    out_dir = Path(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    with atomic_dir(out_dir, overwrite=True) as tmp:
        atomic_write_json(tmp / "config.json", {**run.config, "dataset": str(dataset.root), "provenance": env.provenance()})
        if (out_dir / CHECKPOINT_FILE).is_file():  # the final checkpoint fit() wrote there
            shutil.copy2(out_dir / CHECKPOINT_FILE, tmp / CHECKPOINT_FILE)
        save_parameters(tmp / "params.npz", run.model.parameters())
        atomic_write_json(tmp / "history.json", run.train.history)
        atomic_write_json(tmp / "metrics.json", {**run.metrics(), "provenance": env.provenance()})
        (tmp / "test").mkdir()
        for name, rendered in zip(test_names, run.test.renders):
            stem = Path(name).name
            write_exr(tmp / "test" / f"{stem}.exr", np.concatenate([rendered.rgb, rendered.opacity[..., None]], axis=-1))
            write_png(tmp / "test" / f"{stem}.png", rendered.rgb)


def resume_run(run_dir: Path, train_overrides: Mapping[str, Any] | None = None, *, progress: bool = True,
               dataset: Dataset | None = None) -> RunResult:
    """Continue the run in ``run_dir`` from its checkpoint (``mitsnerf train --resume``).

    Everything comes from the checkpoint's config (method, settings, dataset);
    ``train_overrides`` may change only :data:`RESUMABLE_CHANGES`, e.g. ``{"steps": 2000}``
    to train longer (the learning-rate schedule then stretches to the new length).
    """
    run_dir = Path(run_dir)
    path = run_dir / CHECKPOINT_FILE
    ckpt = load_checkpoint(path)
    train_values = {**(ckpt.config.get("train") or {}), **dict(train_overrides or {})}
    train_config = from_dict(TrainConfig, train_values)
    if dataset is None:
        dataset = open_dataset(ckpt.config, path)
    return fit(dataset, ckpt.config["method"], ckpt.config.get("method_config"), train_config, run_dir,
               progress=progress, resume=True)


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
    else:
        from mitsnerf.data.transforms import read_json

        where = run_dir / "params.npz"
        if not (run_dir / "config.json").is_file() or not where.is_file():
            raise DatasetError(run_dir, None, "neither checkpoint.npz nor config.json + params.npz: not a run directory")
        config = read_json(run_dir / "config.json")
        with np.load(where, allow_pickle=False) as z:
            params = {k: z[k] for k in z.files}
        extra = {}
    dataset = open_dataset(config, where)
    train_views = dataset.views("train")
    info = scene_info(dataset, train_views.images)
    seed = int((config.get("train") or {}).get("seed", 0))
    model, _ = build_model(config["method"], config.get("method_config"), info, seed)
    current = model.parameters()
    missing = sorted(set(current) - set(params))
    if missing:
        raise DatasetError(where, None, f"missing parameters {', '.join(missing)} of method {config['method']!r}")
    model.set_parameters({k: type(current[k])(np.ascontiguousarray(params[k])) for k in current})
    model.load_extra_state(extra)
    return model, dataset, config
