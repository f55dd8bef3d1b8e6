"""Run one benchmark cell: the dataset, :func:`mitsnerf.run.fit` with a held-out PSNR curve, the scores.

:func:`run_cell` is what every executor calls, in-process or in a worker process/Ray task;
it returns the record (JSON data) and the artefacts (``.npz`` bytes) instead of writing
them, so a remote worker needs no shared results directory (the driver writes them).
The fit's own run directory (``cell/run``) is written by the worker where it runs.
"""

from __future__ import annotations

import io
import math
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from mitsnerf.bench.cells import RECORD_FORMAT, Cell
from mitsnerf.bench.scores import density_scores, image_scores, optical_depth_scores

PEAK_MEMORY_NOTE = ("peak_rss_mb: RSS high-water mark (resource.getrusage ru_maxrss) of the process that ran "
                    "the cell, read when it ended; in a reused process (the sequential executor) it includes "
                    "whatever ran there before (earlier cells, ground-truth rendering)")


def peak_rss_mb() -> float | None:
    """The process's RSS high-water mark in MiB (``getrusage``), None where unavailable."""
    try:
        import resource
    except ImportError:  # pragma: no cover (Windows)
        return None
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / (1024.0 * 1024.0) if sys.platform == "darwin" else peak / 1024.0


class CurveRecorder:
    """The trainer's log hook: held-out PSNR at ``points`` instants spread evenly over the budget.

    The budget fraction of a log entry is ``max(step / steps, seconds / budget_seconds)`` (the
    learning-rate schedule's); each time it passes the next ``k / points`` the first
    ``len(cameras)`` test views are rendered and scored. The trainer keeps the hook's time off
    its clock, so evaluation does not eat into the training budget; it is summed in
    ``eval_seconds``. Each evaluation adds ``psnr_heldout`` (and ``psnr_heldout_medium``) to the
    history entry.
    """

    def __init__(self, images: np.ndarray, cameras, masks: np.ndarray | None, pixel_center: float,
                 steps: int, seconds: float, points: int) -> None:
        self.images, self.cameras, self.masks = images, list(cameras), masks
        self.pixel_center, self.steps, self.seconds, self.n_points = pixel_center, steps, seconds, points
        self.points: list[dict[str, Any]] = []
        self.done = 0
        self.eval_seconds = 0.0

    def fraction(self, step: int, seconds: float) -> float:
        frac = step / self.steps
        if self.seconds:
            frac = max(frac, seconds / self.seconds)
        return min(frac, 1.0)

    def __call__(self, entry: dict, model) -> None:
        if not self.n_points:
            return
        frac = self.fraction(entry["step"], entry["seconds"])
        if frac + 1e-9 < (self.done + 1) / self.n_points:
            return
        self.done = min(self.n_points, int(math.floor(frac * self.n_points + 1e-9)))
        start = time.perf_counter()
        from mitsnerf.evaluate import render_camera

        renders = np.stack([render_camera(model, cam, pixel_center=self.pixel_center).rgb for cam in self.cameras])
        scores = image_scores(renders, self.images, self.masks, with_ssim=False)
        point = {"step": int(entry["step"]), "seconds": float(entry["seconds"]),
                 "psnr": scores["psnr_test"], "psnr_medium": scores.get("psnr_test_medium")}
        self.points.append(point)
        entry["psnr_heldout"], entry["psnr_heldout_medium"] = point["psnr"], point["psnr_medium"]
        self.eval_seconds += time.perf_counter() - start


def _open_dataset(cell: Cell, progress: bool):
    """The cell's dataset: the driver's copy, else generated (cached) under the cell's data root."""
    from mitsnerf.data.dataset import load_dataset

    path = Path(cell.dataset_dir)
    if (path / "manifest.json").is_file():
        return load_dataset(path)
    from mitsnerf.scene.generate import generate_dataset
    from mitsnerf.scene.spec import parse_scene

    spec = parse_scene(dict(cell.spec), f"<{cell.bench}: scene {cell.scene}>")
    return load_dataset(generate_dataset(spec, Path(cell.data_root), progress=progress))


def _subset_mean(values: list, k: int) -> float | None:
    vals = [v for v in values[:k] if v is not None]
    return float(np.mean(vals)) if vals else None


def run_cell(cell: Cell, *, progress: bool = False, threads: int = 0, executor: str = "sequential",
             fresh_process: bool = False) -> tuple[dict[str, Any], bytes]:
    """Train and score one cell; returns ``(record, artefacts)`` (see :mod:`mitsnerf.bench.cells`).

    ``threads``: Dr.Jit worker threads for this process (0: leave as is). ``executor`` and
    ``fresh_process`` are recorded next to the peak-memory figure.
    """
    import mitsnerf  # noqa: F401  (libLLVM before drjit, in a fresh worker)
    from mitsnerf import env

    env.set_variant(cell.variant)
    import drjit as dr

    from mitsnerf.config import from_dict
    from mitsnerf.bench.config import EvalConfig
    from mitsnerf.run import fit, medium_masks, true_sigma_t
    from mitsnerf.train import TrainConfig

    if threads:
        dr.set_thread_count(int(threads))
    started = time.time()
    rss_before = peak_rss_mb()
    evalc = from_dict(EvalConfig, dict(cell.eval))
    train_config = from_dict(TrainConfig, dict(cell.train))
    dataset = _open_dataset(cell, progress)
    test = dataset.views("test")
    pc = test.pixel_center
    sigma_t = true_sigma_t(dataset)
    masks = medium_masks(sigma_t, test.cameras, pc) if sigma_t is not None else None

    k = len(test.cameras) if evalc.curve_views == 0 else min(evalc.curve_views, len(test.cameras))
    curve = CurveRecorder(test.images[:k], test.cameras[:k], None if masks is None else masks[:k], pc,
                          train_config.steps, train_config.seconds, evalc.curve_points)
    run = fit(dataset, cell.method, dict(cell.method_config), train_config, Path(cell.out_dir) / "run",
              progress=progress, max_train_eval_views=evalc.train_eval_views, on_log=curve,
              test_masks=masks)

    preds = np.stack([r.rgb for r in run.test.renders])
    metrics: dict[str, Any] = {}
    base = run.metrics()
    for key in ("psnr_train", "train_seconds", "steps", "rays_per_s", "samples_per_s", "num_parameters", "eval_seconds"):
        metrics[key] = base[key]
    metrics.update(image_scores(preds, test.images, masks))
    floor = (dataset.manifest or {}).get("noise_floor") or {}
    metrics["noise_floor_psnr"] = floor.get("psnr")
    metrics["noise_floor_psnr_medium"] = floor.get("psnr_medium")
    metrics["noise_floor_psnr_per_view"] = floor.get("psnr_per_view")
    metrics["curve_eval_seconds"] = curve.eval_seconds

    slices: dict[str, np.ndarray] = {}
    if sigma_t is not None:
        start = time.perf_counter()
        dens, slices = density_scores(run.model, sigma_t, evalc.density_resolution)
        metrics.update(dens)
        metrics.update(optical_depth_scores(run.model, sigma_t, test.cameras, pc, evalc.od_samples))
        metrics["density_eval_seconds"] = time.perf_counter() - start
    else:
        metrics["density_note"] = "the dataset has no true sigma_t grid"

    points = list(curve.points)
    if evalc.curve_points and (not points or points[-1]["step"] != run.train.steps):
        points.append({"step": run.train.steps, "seconds": run.train.seconds,
                       "psnr": _subset_mean(metrics["psnr_test_per_view"], k),
                       "psnr_medium": _subset_mean(metrics.get("psnr_test_medium_per_view") or [], k)})
    metrics["peak_rss_mb"] = peak_rss_mb()

    record = {
        "record_format": RECORD_FORMAT,
        "key": cell.key,
        "bench": cell.bench,
        "quick": cell.quick,
        "scene": cell.scene,
        "method": cell.label,
        "method_name": cell.method,
        "seed": cell.seed,
        "config_hash": cell.config_hash,
        "code_version": cell.code_version,
        "config": cell.identity(),
        "dataset": str(dataset.root),
        "metrics": metrics,
        "curve": {"points": points, "views": k,
                  "note": f"held-out PSNR of the first {k} test views (linear, clipped); seconds exclude evaluation"},
        "history": run.train.history,
        "worker": {"executor": executor, "host": platform.node(), "pid": os.getpid(), "fresh_process": fresh_process,
                   "threads": dr.thread_count(), "peak_rss_mb_at_start": rss_before, "peak_memory_note": PEAK_MEMORY_NOTE},
        "provenance": env.provenance(),
        "started": started,
        "finished": time.time(),
    }
    v = min(evalc.report_view, len(test.cameras) - 1)
    arrays = {"ref": np.asarray(test.images[v], np.float32), "render": preds[v].astype(np.float32), "view": np.int32(v)}
    if masks is not None:
        arrays["mask"] = masks[v]
    arrays.update(slices)
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    return record, buf.getvalue()
