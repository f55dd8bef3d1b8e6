"""Run one benchmark cell: the dataset, :func:`mitsnerf.runs.fit.fit` with a held-out PSNR curve, the scores.

:func:`run_cell` is what every executor calls, in-process or in a worker process/Ray task;
it returns the record (JSON data) and the artefacts (``.npz`` bytes) instead of writing
them, so a remote worker needs no shared results directory (the driver writes them).
The fit's own run directory (``cell/run``) is written by the worker where it runs; a cell whose settings name
another row's result (``"@LABEL"``) reads that cell's ``run/`` there (:func:`mitsnerf.bench.references.
resolved_config`).
"""

from __future__ import annotations

import io
import os
import platform
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from mitsnerf.bench.cells import IN_FLIGHT_FILE, RECORD_FORMAT, Cell, SceneData
from mitsnerf.bench.references import resolved_config
from mitsnerf.oracle.rungs import ceiling_figures
from mitsnerf.scoring.images import image_scores
from mitsnerf.train import memory


class CurveRecorder:
    """The trainer's log hook: held-out PSNR at ``points`` steps spread evenly over the step budget.

    Evaluation ``k`` runs at the first log entry whose step reaches ``k / points`` of
    ``steps`` (a function of the step alone, so the curve's steps do not depend on the
    machine's load); the first ``len(cameras)`` test views are rendered with the run's
    footprint and scored. The trainer keeps the hook's time off its clock; it is summed in
    ``eval_seconds``. Each evaluation adds ``psnr_heldout`` (and ``psnr_heldout_medium``) to the
    history entry.
    """

    def __init__(self, reference, steps: int, points: int, footprint: int) -> None:
        self.reference, self.steps, self.n_points, self.footprint = reference, steps, points, footprint
        self.points: list[dict[str, Any]] = []
        self.done = 0
        self.eval_seconds = 0.0

    def restore(self, history: list[dict]) -> None:
        """The points an interrupted run evaluated before its checkpoint (kept in its history entries)."""
        self.points = [{"step": int(e["step"]), "seconds": float(e["seconds"]), "psnr": e["psnr_heldout"],
                        "psnr_medium": e.get("psnr_heldout_medium")} for e in history if "psnr_heldout" in e]
        if self.points:
            self.done = min(self.n_points, self.points[-1]["step"] * self.n_points // self.steps)

    def __call__(self, entry: dict, model) -> None:
        if not self.n_points or entry["step"] * self.n_points < (self.done + 1) * self.steps:
            return
        self.done = min(self.n_points, entry["step"] * self.n_points // self.steps)
        start = time.perf_counter()
        from mitsnerf.train.evaluate import render_views, stack_rgb

        ref = self.reference
        renders, _ = render_views(model, ref.cameras, pixel_center=ref.pixel_center, footprint=self.footprint)
        scores = image_scores(stack_rgb(renders), ref.images, ref.masks, with_ssim=False)
        point = {"step": int(entry["step"]), "seconds": float(entry["seconds"]),
                 "psnr": scores["psnr_test"], "psnr_medium": scores.get("psnr_test_medium")}
        self.points.append(point)
        entry["psnr_heldout"], entry["psnr_heldout_medium"] = point["psnr"], point["psnr_medium"]
        self.eval_seconds += time.perf_counter() - start


def time_to_targets(points: list[dict[str, Any]], targets) -> dict[str, Any]:
    """Training seconds and steps at the first held-out evaluation whose medium PSNR reaches each target.

    Keys ``seconds_to_<X>db`` and ``steps_to_<X>db`` (None: not reached); the resolution is
    the curve's spacing.

    >>> time_to_targets([{"step": 10, "seconds": 2.0, "psnr_medium": 31.0},
    ...                  {"step": 20, "seconds": 4.0, "psnr_medium": 36.0}], (30, 35, 40))["seconds_to_35db"]
    4.0
    """
    out: dict[str, Any] = {}
    for target in targets:
        hit = next((p for p in points if p.get("psnr_medium") is not None and p["psnr_medium"] >= target), None)
        tag = f"{target:g}db"
        out[f"seconds_to_{tag}"] = None if hit is None else hit["seconds"]
        out[f"steps_to_{tag}"] = None if hit is None else hit["step"]
    return out


def _open_dataset(cell: Cell, progress: bool):
    """The cell's dataset: the driver's copy (whose hashes the driver verified when it found it in
    the cache; the grids and views are checked again here), else generated (cached, verified) under
    the cell's data root."""
    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.data.verify import verify_dataset

    path = Path(cell.dataset_dir)
    if (path / "manifest.json").is_file():
        dataset = load_dataset(path)
        verify_dataset(dataset, hashes=False)
        return dataset
    from mitsnerf.generate import generate_dataset
    from mitsnerf.scene.spec import parse_scene

    spec = parse_scene(dict(cell.spec), f"<{cell.bench}: scene {cell.scene}>")
    return load_dataset(generate_dataset(spec, Path(cell.data_root), progress=progress))


def cell_oracle(cell: Cell | SceneData, dataset=None, log=lambda line: None, reference=None):
    """The cached oracle (:class:`mitsnerf.oracle.cache.Oracle`) of the cell's dataset at its eval
    footprint, computed and cached first if missing (with ``reference``, the test views'
    :class:`~mitsnerf.scoring.reference.Reference`, where the caller has it); None when the cell has none
    (or foreign data)."""
    from mitsnerf.config import from_dict
    from mitsnerf.data.dataset import load_dataset
    from mitsnerf.oracle.cache import OracleConfig, ensure_oracle

    if cell.oracle is None:
        return None
    if dataset is None:
        if not (Path(cell.dataset_dir) / "manifest.json").is_file():
            return None
        dataset = load_dataset(Path(cell.dataset_dir))
    config = from_dict(OracleConfig, dict(cell.oracle))
    return ensure_oracle(dataset, config, int(cell.eval.get("footprint", 1)), log, reference)


def oracle_summary(oracle, footprint: int) -> dict[str, Any] | None:
    """What a cell's record keeps of its dataset's oracle: where, its settings and medium PSNRs."""
    if oracle is None:
        return None
    info = oracle.info
    return {"path": str(oracle.path), "key": info.get("key"), "config": info.get("config"),
            "footprint": footprint, "psnr_test_medium": info.get("psnr_test_medium"),
            "psnr_test_medium_without_mc": oracle.metrics(footprint).get("psnr_test_medium_without_mc"),
            "psnr_test": {k: s.get("psnr_test") for k, s in oracle.scores.items()},
            "psnr_test_per_view": oracle.metrics(footprint).get("psnr_test_per_view"),
            "error_split": info.get("error_split"), "seconds": info.get("seconds")}



@dataclass
class SceneLoads:
    """What the cells of one scene share within one process, loaded once: the dataset (its views read once),
    its oracle and the test views' reference. Holds the last scene only (cells run scene by scene, so a sweep
    loads each scene once and memory holds one). The sequential executor passes one to every cell; a pool or
    Ray worker runs one cell per process and loads its own."""

    key: tuple | None = None
    loaded: tuple | None = None
    loads: int = 0
    """How many times a scene was loaded (what the tests count)."""

    def scene(self, cell: Cell, progress: bool) -> tuple[Any, Any, Any]:
        """``(dataset, oracle, reference)`` of ``cell``'s scene, loaded unless it was the last one asked for."""
        import json

        from mitsnerf.scoring.reference import load_reference

        key = (cell.dataset_dir, json.dumps(cell.oracle, sort_keys=True), cell.eval.get("footprint", 1))
        if self.key != key or self.loaded is None:
            dataset = _open_dataset(cell, progress)
            ref = load_reference(dataset, "test")
            self.key, self.loaded = key, (dataset, cell_oracle(cell, dataset, reference=ref), ref)
            self.loads += 1
        return self.loaded


def _resumable(cell: Cell) -> bool:
    """Whether ``CELL/run`` holds an interrupted run of this very cell (same config and code)."""
    from mitsnerf.bench.cells import read_record
    from mitsnerf.runs.directory import inspect_run_dir

    mark = read_record(cell.path, IN_FLIGHT_FILE) or {}
    return (mark.get("config_hash"), mark.get("code_version")) == (cell.config_hash, cell.code_version) \
        and inspect_run_dir(cell.path / "run").kind == "interrupted"


def _fit(cell: Cell, method_config: dict, dataset, train_config, evalc, curve: CurveRecorder, ref,
         oracle: dict | None, progress: bool):
    """:func:`mitsnerf.runs.fit.fit` of ``method_config`` (the cell's, its ``"@LABEL"`` settings resolved) into
    ``CELL/run``, claimed (locked); an interrupted run of the cell is continued. A fresh run removes the old
    run's ``export/`` first (made for a row that starts from this one: it would be stale). Returns ``(run, step
    resumed from or None)``."""
    import shutil

    from mitsnerf.data.atomic import atomic_write_json
    from mitsnerf.runs.directory import claim_run_dir
    from mitsnerf.runs.fit import fit
    from mitsnerf.train.checkpoint import CHECKPOINT_FILE, load_checkpoint

    run_dir = cell.path / "run"
    resume = _resumable(cell)
    with claim_run_dir(run_dir, resume=resume, force=not resume, option="cell run directory"):
        start = None
        if resume:
            ckpt = load_checkpoint(run_dir / CHECKPOINT_FILE)
            curve.restore(ckpt.history)
            start = ckpt.step
        else:
            shutil.rmtree(run_dir / "export", ignore_errors=True)
            atomic_write_json(cell.path / IN_FLIGHT_FILE, {"key": cell.key, "config_hash": cell.config_hash,
                                                           "code_version": cell.code_version})
        return fit(dataset, cell.method, method_config, train_config, run_dir, eval_config=evalc,
                   progress=progress, on_log=curve, reference=ref, oracle=oracle, resume=resume), start


def run_cell(cell: Cell, *, progress: bool = False, threads: int = 0, executor: str = "sequential",
             fresh_process: bool = False, loads: SceneLoads | None = None) -> tuple[dict[str, Any], bytes]:
    """Train and score one cell; returns ``(record, artefacts)`` (see :mod:`mitsnerf.bench.cells`).

    ``threads``: Dr.Jit worker threads for this process (0: leave as is). ``executor`` and
    ``fresh_process`` are recorded next to the peak-memory figure. ``loads``: the scene loads shared with the
    cells run before in this process (None: load the scene for this cell alone).
    """
    import mitsnerf  # noqa: F401  (libLLVM before drjit, in a fresh worker)
    from mitsnerf import env

    env.set_variant(cell.variant)
    import drjit as dr

    from mitsnerf.config import from_dict
    from mitsnerf.train import TrainConfig
    from mitsnerf.train.evaluate import EvalConfig

    if threads:
        dr.set_thread_count(int(threads))
    started = time.time()
    rss_before = memory.peak_rss_mb()
    evalc = from_dict(EvalConfig, dict(cell.eval))
    train_config = from_dict(TrainConfig, dict(cell.train))
    method_config = resolved_config(cell, progress)  # "@LABEL" -> the referred cell's run (exported)
    dataset, oracle, ref = (loads if loads is not None else SceneLoads()).scene(cell, progress)
    k = len(ref.cameras) if evalc.curve_views == 0 else min(evalc.curve_views, len(ref.cameras))
    curve_ref = replace(ref, images=ref.images[:k], cameras=ref.cameras[:k],
                        masks=None if ref.masks is None else ref.masks[:k])
    curve = CurveRecorder(curve_ref, train_config.steps, evalc.curve_points, evalc.footprint)
    run, resumed_from = _fit(cell, method_config, dataset, train_config, evalc, curve, ref,
                             None if oracle is None else oracle.metrics(evalc.footprint), progress)

    metrics = run.metrics()  # its peaks counted by fit from its start (mitsnerf.train.memory), its scene loaded
    metrics.pop("method", None)
    rss_reset = metrics.pop("peak_rss_reset", None)
    metrics["curve_eval_seconds"] = curve.eval_seconds
    points = list(curve.points)
    if evalc.curve_points and (not points or points[-1]["step"] != run.train.steps):
        last = image_scores(np.stack([r.rgb for r in run.renders[:k]]), curve_ref.images, curve_ref.masks,
                            with_ssim=False)
        points.append({"step": run.train.steps, "seconds": run.train.seconds, "psnr": last["psnr_test"],
                       "psnr_medium": last.get("psnr_test_medium")})
    metrics.update(time_to_targets(points, evalc.psnr_targets))
    basis = run.model.rung_basis() if run.model.rung == "single scattering" else None
    metrics.update(ceiling_figures(run.model.rung, basis, oracle, dataset, evalc.footprint, ref, metrics))
    # the high-water marks since fit began counting, the ceiling's renders included
    metrics["peak_memory_mb"], metrics["peak_rss_mb"] = memory.peak_memory_mb(), memory.peak_rss_mb()

    record = _record(cell, dataset, metrics, points, k, evalc, run.train.history)
    record["oracle"] = oracle_summary(oracle, evalc.footprint)
    record["worker"] = {"executor": executor, "host": platform.node(), "pid": os.getpid(),
                        "fresh_process": fresh_process, "threads": dr.thread_count(), "resumed_from_step": resumed_from,
                        "peak_rss_mb_at_start": rss_before, "peak_rss_reset": rss_reset,
                        "peak_memory_note": memory.PEAK_MEMORY_NOTE}
    record["started"], record["finished"] = started, time.time()
    return record, _artefacts(run, ref, evalc.report_view)


def _record(cell: Cell, dataset, metrics: dict, points: list, k: int, evalc, history: list) -> dict[str, Any]:
    from mitsnerf import env

    return {
        "record_format": RECORD_FORMAT, "key": cell.key, "bench": cell.bench, "quick": cell.quick,
        "scene": cell.scene, "method": cell.label, "method_name": cell.method, "seed": cell.seed,
        "config_hash": cell.config_hash, "code_version": cell.code_version, "config": cell.identity(),
        "dataset": str(dataset.root), "metrics": metrics,
        "curve": {"points": points, "views": k, "footprint": evalc.footprint,
                  "note": f"held-out PSNR of the first {k} test views (linear, clipped) at steps k/"
                          f"{evalc.curve_points} of the budget; seconds exclude evaluation"},
        "history": history, "provenance": env.provenance(),
    }


def _artefacts(run, ref, report_view: int) -> bytes:
    """The report's arrays (``.npz`` bytes): one test view, its render and mask, the density slices."""
    v = min(report_view, len(ref.cameras) - 1)
    arrays = {"ref": np.asarray(ref.images[v], np.float32), "render": run.renders[v].rgb.astype(np.float32),
              "view": np.int32(v)}
    if ref.masks is not None:
        arrays["mask"] = ref.masks[v]
    arrays.update(run.slices)
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    return buf.getvalue()
