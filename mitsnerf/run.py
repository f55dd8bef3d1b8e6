"""One training run end to end: dataset -> method -> training -> evaluation -> files.

``fit`` is what ``mitsnerf train`` and every benchmark cell call. A run directory
holds ``config.json``, ``params.npz``, ``history.json``, ``metrics.json`` and the
rendered test views (``test/r_*.exr`` linear, ``.png`` sRGB previews); it is
written inside a temporary directory and renamed when complete.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from mitsnerf import env
from mitsnerf.config import from_dict, to_dict
from mitsnerf.data.atomic import atomic_dir, atomic_write_json
from mitsnerf.data.dataset import Dataset
from mitsnerf.data.images import write_exr, write_png
from mitsnerf.errors import DatasetError
from mitsnerf.evaluate import EvalResult, evaluate_views, render_camera
from mitsnerf.fields.grid import GridField
from mitsnerf.math.metrics import psnr
from mitsnerf.methods import get_method
from mitsnerf.methods.base import Model, SceneInfo, num_parameters
from mitsnerf.render.background import make_background
from mitsnerf.render.rays import BOX_MAX, BOX_MIN
from mitsnerf.render.volume import render_rays
from mitsnerf.train import PixelData, TrainConfig, TrainResult, train

MEDIUM_OPACITY_THRESHOLD = 1e-3
"""A pixel 'sees the medium' when the true medium's opacity along its ray exceeds this."""


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
    )


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
    """(V, H, W) bool: pixels whose rays cross the true medium (opacity > threshold)."""
    field = GridField.from_arrays(sigma_t)
    truth = lambda o, d: render_rays(field, o, d, 256)  # noqa: E731
    return np.stack([render_camera(truth, cam, pixel_center=pixel_center).opacity > MEDIUM_OPACITY_THRESHOLD for cam in cameras])


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
) -> RunResult:
    """Train ``method`` on ``dataset`` and evaluate it on every test view."""
    train_views = dataset.views("train")
    test_views = dataset.views("test")
    pixel_center = train_views.pixel_center
    info = scene_info(dataset, train_views.images)
    model, config = build_model(method, method_overrides, info, train_config.seed)
    base_lr = train_config.lr or getattr(config, "lr", 1e-2)
    data = PixelData.from_views(train_views.images, train_views.cameras, pixel_center)
    result, _ = train(model, data, train_config, base_lr, progress=progress)

    test_eval = evaluate_views(model, test_views.images, test_views.cameras, pixel_center=pixel_center)
    k = min(max_train_eval_views, len(train_views.cameras))
    train_eval = evaluate_views(model, train_views.images[:k], train_views.cameras[:k], pixel_center=pixel_center, keep_renders=False)

    psnr_medium = None
    sigma_t = true_sigma_t(dataset)
    if sigma_t is not None:
        masks = medium_masks(sigma_t, test_views.cameras, pixel_center)
        preds = np.clip(np.stack([r.rgb for r in test_eval.renders]), 0.0, 1.0)
        refs = np.clip(test_views.images, 0.0, 1.0)
        if masks.any():
            psnr_medium = float(np.mean([psnr(p, r, mask=m) for p, r, m in zip(preds, refs, masks) if m.any()]))

    run = RunResult(
        method=method,
        config={"method": method, "method_config": to_dict(config), "train": to_dict(train_config)},
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
        save_parameters(tmp / "params.npz", run.model.parameters())
        atomic_write_json(tmp / "history.json", run.train.history)
        atomic_write_json(tmp / "metrics.json", {**run.metrics(), "provenance": env.provenance()})
        (tmp / "test").mkdir()
        for name, rendered in zip(test_names, run.test.renders):
            stem = Path(name).name
            write_exr(tmp / "test" / f"{stem}.exr", np.concatenate([rendered.rgb, rendered.opacity[..., None]], axis=-1))
            write_png(tmp / "test" / f"{stem}.png", rendered.rgb)
