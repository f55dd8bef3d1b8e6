"""Run a benchmark: every (scene, method, seed) cell, then one table.

Ground truth comes from the dataset cache (generated on first use); each cell's
files go to ``results/<bench>/<scene>/<label>-seed<k>/``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mitsnerf import env
from mitsnerf.bench.config import BenchConfig
from mitsnerf.bench.tables import csv_table, markdown_table
from mitsnerf.config import from_dict
from mitsnerf.data.atomic import atomic_write_json, atomic_write_text
from mitsnerf.data.dataset import load_dataset
from mitsnerf.run import fit
from mitsnerf.scene.generate import generate_dataset
from mitsnerf.scene.spec import load_scene
from mitsnerf.train import TrainConfig

DATA_ENV = "MITSNERF_DATA"

COLUMNS = (
    ("scene", "scene", 0),
    ("method", "method", 0),
    ("seed", "seed", 0),
    ("psnr_train", "PSNR train", 2),
    ("psnr_test", "PSNR test", 2),
    ("psnr_test_medium", "PSNR test (medium)", 2),
    ("noise_floor_psnr", "GT noise floor", 2),
    ("ssim_test", "SSIM test", 4),
    ("train_seconds", "train s", 1),
    ("steps", "steps", 0),
    ("rays_per_s", "rays/s", 0),
    ("samples_per_s", "samples/s", 0),
)
BEST = {"psnr_test": "max", "psnr_test_medium": "max", "ssim_test": "max", "psnr_train": "max"}


def default_data_root() -> Path:
    return Path(os.environ.get(DATA_ENV) or "data")


@dataclass(frozen=True)
class BenchOptions:
    quick: bool = False
    data_root: Path = Path("data")
    results_root: Path = Path("results")
    progress: bool = True


def run_benchmark(config: BenchConfig, options: BenchOptions) -> tuple[list[dict], str]:
    """Run every cell; returns (rows, Markdown table). Writes table.md/.csv and results.json."""
    out_root = options.results_root / (config.name + ("-quick" if options.quick else ""))
    rows: list[dict] = []
    for scene_name in config.scenes:
        spec = load_scene(scene_name)
        if options.quick and config.quick.scene:
            spec = spec.with_overrides(dict(config.quick.scene))
        dataset_dir = generate_dataset(spec, options.data_root, progress=options.progress)
        dataset = load_dataset(dataset_dir)
        floor = (dataset.manifest.get("noise_floor") or {}).get("psnr")
        for method in config.methods:
            method_config = dict(method.config)
            train_values = dict(method.train)
            if options.quick:
                method_config.update(config.quick.config)
                train_values.update(config.quick.train)
            for seed in config.seeds:
                train_config = from_dict(TrainConfig, {**train_values, "seed": seed})
                cell_dir = out_root / scene_name / f"{method.label}-seed{seed}"
                if options.progress:
                    print(f"[{scene_name} / {method.label} / seed {seed}] training ...", flush=True)
                run = fit(dataset, method.name, method_config, train_config, cell_dir, progress=options.progress)
                row = {"scene": scene_name, "method": method.label, "seed": seed, "noise_floor_psnr": floor, **run.metrics()}
                row["method"] = method.label
                rows.append(row)
    table = markdown_table(rows, COLUMNS, BEST)
    out_root.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out_root / "table.md", table + "\n")
    atomic_write_text(out_root / "table.csv", csv_table(rows, [c[0] for c in COLUMNS]))
    atomic_write_json(out_root / "results.json", {"benchmark": config.name, "quick": options.quick, "provenance": env.provenance(), "rows": rows})
    return rows, table
